// NumPy .npz reader and writer: the zip container is libzip's (zip.h), the
// .npy members are parsed here (npy.h).
//
// .npz (numpy.savez / savez_compressed): a zip archive whose members
// `<key>.npy` are .npy files, stored (method 0) or deflated (method 8).
// numpy writes every member with ZIP64 extra fields (force_zip64=True);
// libzip reads those, data descriptors and the ZIP64 end records, and checks
// each member's CRC-32. Members whose name does not end in ".npy" are
// skipped. Encrypted members and compression methods other than
// stored/deflate are unsupported (IoError).
#pragma once

#include "framework/io/npy.h"
#include "framework/io/zip.h"

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// Random access to the members of an .npz file. The whole file is read
/// into memory and its central directory parsed on construction; members
/// are decoded on demand, so one unsupported member (e.g. a pickled object
/// array) does not prevent reading the others.
class NpzReader {
 public:
  /// Throws IoError if the file cannot be read or is not a valid zip.
  explicit NpzReader(std::filesystem::path path);

  const std::filesystem::path& path() const { return path_; }
  /// Member keys (names without ".npy"), sorted.
  std::vector<std::string> Keys() const;
  bool Contains(std::string_view key) const;
  /// Decodes member `key`; IoError naming the file and key if absent,
  /// corrupt (CRC, truncated, bad deflate stream) or of unsupported dtype.
  NpyArray Read(std::string_view key) const;

 private:
  std::filesystem::path path_;
  ZipReader zip_;
  /// The ".npy" members by key (name without ".npy").
  std::map<std::string, ZipEntry, std::less<>> entries_;
};

/// Reads every member of an .npz file (key = member name without ".npy").
/// Throws IoError naming the file and member on any problem, including an
/// unsupported dtype in any member.
std::map<std::string, NpyArray> ReadNpz(const std::filesystem::path& path);

/// Options of WriteNpz.
struct NpzWriteOptions {
  /// Deflate members (numpy.savez_compressed) instead of storing them
  /// (numpy.savez). ZIP64 records are written where sizes need them.
  bool compress = false;
};

/// Writes `arrays` as an .npz (members "<key>.npy" in key order) atomically
/// (temp file + rename). Fixed timestamps, so equal input gives equal bytes.
void WriteNpz(const std::filesystem::path& path,
              const std::map<std::string, NpyArray>& arrays,
              const NpzWriteOptions& options = {});

}  // namespace soma
