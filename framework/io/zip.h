// Zip archives through libzip (Debian libzip-dev), and gzip/zlib stream
// decompression through zlib.
//
// Reading: the archive is held in memory and opened with libzip's
// consistency checks (ZIP_CHECKCONS); ZIP64 records, data descriptors and
// stored or deflated members are libzip's business, and a member's CRC-32 is
// checked when it is read to its end. Errors are one-line IoErrors naming
// the source (and the member).
//
// Writing: members are added in call order with a fixed timestamp
// (1980-01-01 00:00 local time), so equal input gives equal bytes; libzip
// writes ZIP64 records where sizes or offsets need them.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// One member of a zip archive as libzip's zip_stat reports it.
struct ZipEntry {
  std::string name;     // member name in the archive ("key.npy")
  uint64_t index = 0;   // libzip's index of the member
  uint16_t method = 0;  // 0 stored, 8 deflate
  uint32_t crc32 = 0;
  uint64_t compressed_size = 0;
  uint64_t uncompressed_size = 0;
};

/// Random access to the members of an in-memory zip archive. Read() may be
/// called from several threads (libzip archives are not thread-safe, so
/// reads are serialised).
class ZipReader {
 public:
  /// Opens `bytes` as a zip archive. `source` (the file name) prefixes every
  /// error. Throws IoError "<source>: not a zip archive", "<source>:
  /// truncated zip archive ..." or "<source>: corrupt zip archive ...".
  ZipReader(std::string bytes, std::string source);
  ~ZipReader();
  ZipReader(ZipReader&&) noexcept;
  ZipReader& operator=(ZipReader&&) noexcept;

  const std::string& source() const { return source_; }
  /// Every member, in central-directory order.
  const std::vector<ZipEntry>& entries() const { return entries_; }
  /// The uncompressed bytes of `entry` (one of entries()). Throws IoError
  /// "<source>: entry '<name>': ..." for an encrypted member, an unsupported
  /// method, truncated or corrupt data, or a CRC-32 mismatch.
  std::string Read(const ZipEntry& entry) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string source_;
  std::vector<ZipEntry> entries_;
};

/// Options of ZipWriter.
struct ZipWriteOptions {
  /// Deflate members (method 8) instead of storing them (method 0).
  bool deflate = false;
};

/// Builds a zip archive in memory with libzip: Add() each member, then
/// Finish() writes the archive to `out`. The caller checks the stream state
/// afterwards.
class ZipWriter {
 public:
  explicit ZipWriter(std::ostream& out, ZipWriteOptions options = {});
  ~ZipWriter();
  ZipWriter(const ZipWriter&) = delete;
  ZipWriter& operator=(const ZipWriter&) = delete;

  /// Adds member `name` holding `bytes`. Throws IoError for an empty name, a
  /// name longer than 65535 bytes or a name already added.
  void Add(std::string_view name, std::string_view bytes);
  /// Writes the archive to the stream; call once, last.
  void Finish();

 private:
  struct Impl;
  std::ostream& out_;
  ZipWriteOptions options_;
  std::unique_ptr<Impl> impl_;
};

/// Decompresses a gzip (RFC 1952) or zlib (RFC 1950) stream with zlib,
/// detected from its header; concatenated gzip members are all decoded.
/// Used for .gz assets (e.g. MakeHuman .target.gz). Throws IoError naming
/// `source`.
std::string Gunzip(std::string_view compressed, std::string_view source);

/// Reads and decompresses a gzip file (see Gunzip).
std::string ReadGzipFile(const std::filesystem::path& path);

}  // namespace soma
