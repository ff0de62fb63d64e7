// A self-contained zip container (PKWARE APPNOTE 6.3) reader and writer over
// zlib, and gzip/zlib stream decompression.
//
// Reading: the archive is held in memory; members are located through the
// central directory (so data descriptors, flag bit 3, are handled), ZIP64
// extra fields in the central directory and the ZIP64 end-of-central-
// directory record are honoured, and a member's CRC-32 is checked when it is
// read. Members are stored (method 0) or deflated (method 8); encrypted
// members and other methods are an IoError when read.
//
// Writing: members are streamed in call order with fixed DOS timestamps
// (1980-01-01 00:00), so equal input gives equal bytes; ZIP64 records are
// written when sizes or offsets need them, or always with force_zip64 (as
// numpy does).
#pragma once

#include <cstdint>
#include <filesystem>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

/// One member of a zip archive as its central-directory record gives it
/// (ZIP64 values already applied).
struct ZipEntry {
  std::string name;  // member name in the archive ("key.npy")
  uint16_t flags = 0;
  uint16_t method = 0;  // 0 stored, 8 deflate
  uint32_t crc32 = 0;
  uint64_t compressed_size = 0;
  uint64_t uncompressed_size = 0;
  uint64_t local_header_offset = 0;
};

/// Random access to the members of an in-memory zip archive.
class ZipReader {
 public:
  /// Parses the central directory of `bytes`. `source` (the file name)
  /// prefixes every error. Throws IoError if `bytes` is not a valid zip
  /// (no end record, truncated or corrupt central directory).
  ZipReader(std::string bytes, std::string source);

  const std::string& source() const { return source_; }
  /// Every member, in central-directory order.
  const std::vector<ZipEntry>& entries() const { return entries_; }
  /// The uncompressed bytes of `entry` (one of entries()). Throws IoError
  /// naming "<source>: entry '<name>'" for an encrypted member, a bad local
  /// header, truncated data, an unsupported method, a corrupt deflate
  /// stream or a CRC-32 mismatch.
  std::string Read(const ZipEntry& entry) const;

 private:
  std::string bytes_;
  std::string source_;
  std::vector<ZipEntry> entries_;
};

/// Options of ZipWriter.
struct ZipWriteOptions {
  /// Deflate members (method 8) instead of storing them (method 0).
  bool deflate = false;
  /// Write ZIP64 extra fields and end records even when sizes are small;
  /// sizes and offsets >= 4 GiB always use ZIP64.
  bool force_zip64 = false;
};

/// Streams a zip archive to `out`: Add() writes each member's local header
/// and data, Finish() the central directory and the end records. The
/// caller checks the stream state afterwards.
class ZipWriter {
 public:
  explicit ZipWriter(std::ostream& out, ZipWriteOptions options = {});

  /// Writes member `name` holding `bytes`. Throws IoError for a name longer
  /// than 65535 bytes.
  void Add(std::string_view name, std::string_view bytes);
  /// Writes the central directory and end records; call once, last.
  void Finish();

 private:
  std::ostream& out_;
  ZipWriteOptions options_;
  uint64_t offset_ = 0;  // bytes written so far
  uint64_t num_entries_ = 0;
  std::string central_;  // central-directory records of the members so far
};

/// Decompresses a gzip (RFC 1952) or zlib (RFC 1950) stream, detected from
/// its header; concatenated gzip members are all decoded. Used for .gz
/// assets (e.g. MakeHuman .target.gz). Throws IoError naming `source`.
std::string Gunzip(std::string_view compressed, std::string_view source);

/// Reads and decompresses a gzip file (see Gunzip).
std::string ReadGzipFile(const std::filesystem::path& path);

}  // namespace soma
