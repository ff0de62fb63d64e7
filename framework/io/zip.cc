#include "framework/io/zip.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/little_endian.h"

#include <fmt/format.h>

#include <algorithm>
#include <utility>
#include <zlib.h>

namespace soma {
namespace {

using internal::Le16;
using internal::Le32;
using internal::Le64;
using internal::Put16;
using internal::Put32;
using internal::Put64;

// Zip record signatures (APPNOTE 6.3, sections 4.3.7, 4.3.12, 4.3.14-16).
constexpr uint32_t kLocalHeaderSignature = 0x04034b50;
constexpr uint32_t kCentralHeaderSignature = 0x02014b50;
constexpr uint32_t kEndOfCentralDirSignature = 0x06054b50;
constexpr uint32_t kZip64EndOfCentralDirSignature = 0x06064b50;
constexpr uint32_t kZip64LocatorSignature = 0x07064b50;
constexpr uint16_t kZip64ExtraId = 0x0001;
constexpr size_t kLocalHeaderSize = 30;
constexpr size_t kCentralHeaderSize = 46;
constexpr size_t kEndOfCentralDirSize = 22;
constexpr size_t kZip64LocatorSize = 20;
constexpr size_t kZip64EndOfCentralDirSize = 56;
constexpr uint32_t kMax32 = 0xFFFFFFFFu;
constexpr uint16_t kMax16 = 0xFFFFu;
// DOS date 1980-01-01, time 00:00 (deterministic archives).
constexpr uint16_t kDosDate = (0 << 9) | (1 << 5) | 1;
constexpr uint16_t kDosTime = 0;
// Deflate's maximum expansion is 258 bytes per 2-bit code, ~1032:1.
constexpr uint64_t kMaxDeflateRatio = 1100;
// zlib's avail_in/avail_out are 32-bit: feed at most this much per call.
constexpr size_t kZlibChunk = size_t{1} << 30;

uint32_t Crc32(std::string_view bytes) {
  uLong crc = crc32(0L, Z_NULL, 0);
  size_t offset = 0;
  while (offset < bytes.size()) {
    const size_t n = std::min(kZlibChunk, bytes.size() - offset);
    crc = crc32(crc,
                reinterpret_cast<const Bytef*>(bytes.data() + offset),
                static_cast<uInt>(n));
    offset += n;
  }
  return static_cast<uint32_t>(crc);
}

// ---------------------------------------------------------------------------
// zlib.

std::string InflateRaw(std::string_view compressed,
                       uint64_t expected_size,
                       std::string_view source) {
  z_stream stream{};
  if (inflateInit2(&stream, -MAX_WBITS) != Z_OK) {
    throw IoError(fmt::format("{}: zlib inflateInit2 failed", source));
  }
  std::string out(expected_size, '\0');
  size_t in_offset = 0;
  size_t out_offset = 0;
  int status = Z_OK;
  while (true) {
    const size_t in_chunk = std::min(kZlibChunk, compressed.size() - in_offset);
    const size_t out_chunk = std::min(kZlibChunk, out.size() - out_offset);
    stream.next_in = reinterpret_cast<Bytef*>(
        const_cast<char*>(compressed.data() + in_offset));
    stream.avail_in = static_cast<uInt>(in_chunk);
    stream.next_out = reinterpret_cast<Bytef*>(out.data() + out_offset);
    stream.avail_out = static_cast<uInt>(out_chunk);
    // A one-byte scratch output lets zlib report data beyond the declared
    // size instead of stalling.
    char scratch = 0;
    if (out_chunk == 0) {
      stream.next_out = reinterpret_cast<Bytef*>(&scratch);
      stream.avail_out = 1;
    }
    status = inflate(&stream, Z_NO_FLUSH);
    const size_t consumed = in_chunk - stream.avail_in;
    const size_t produced = (out_chunk == 0 ? 1 : out_chunk) - stream.avail_out;
    in_offset += consumed;
    if (out_chunk == 0 && produced > 0) {
      inflateEnd(&stream);
      throw IoError(fmt::format(
          "{}: deflate stream holds more than the declared {} bytes",
          source,
          expected_size));
    }
    out_offset += out_chunk == 0 ? 0 : produced;
    if (status == Z_STREAM_END) break;
    if (status != Z_OK && status != Z_BUF_ERROR) {
      const std::string message = stream.msg ? stream.msg : "unknown error";
      inflateEnd(&stream);
      throw IoError(
          fmt::format("{}: corrupt deflate stream ({})", source, message));
    }
    if (consumed == 0 && produced == 0) {
      inflateEnd(&stream);
      throw IoError(
          fmt::format("{}: truncated deflate stream ({} of {} bytes decoded)",
                      source,
                      out_offset,
                      expected_size));
    }
  }
  inflateEnd(&stream);
  if (out_offset != expected_size) {
    throw IoError(fmt::format(
        "{}: deflate stream decodes to {} bytes, the directory says {}",
        source,
        out_offset,
        expected_size));
  }
  return out;
}

std::string DeflateRaw(std::string_view bytes) {
  z_stream stream{};
  if (deflateInit2(&stream,
                   Z_DEFAULT_COMPRESSION,
                   Z_DEFLATED,
                   -MAX_WBITS,
                   8,
                   Z_DEFAULT_STRATEGY) != Z_OK) {
    throw IoError("zlib deflateInit2 failed");
  }
  std::string out;
  size_t in_offset = 0;
  std::vector<char> buffer(1 << 16);
  while (true) {
    const size_t in_chunk = std::min(kZlibChunk, bytes.size() - in_offset);
    stream.next_in =
        reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data() + in_offset));
    stream.avail_in = static_cast<uInt>(in_chunk);
    const bool last = in_offset + in_chunk == bytes.size();
    int status = Z_OK;
    do {
      stream.next_out = reinterpret_cast<Bytef*>(buffer.data());
      stream.avail_out = static_cast<uInt>(buffer.size());
      status = deflate(&stream, last ? Z_FINISH : Z_NO_FLUSH);
      if (status == Z_STREAM_ERROR) {
        deflateEnd(&stream);
        throw IoError("zlib deflate failed");
      }
      out.append(buffer.data(), buffer.size() - stream.avail_out);
    } while (stream.avail_out == 0);
    in_offset += in_chunk;
    if (last && status == Z_STREAM_END) break;
  }
  deflateEnd(&stream);
  return out;
}

// ---------------------------------------------------------------------------
// Zip reading helpers.

// Values from a ZIP64 extended-information extra field (APPNOTE 4.5.3): the
// fields present are those whose 32-bit counterpart is 0xFFFFFFFF, in the
// order uncompressed size, compressed size, local header offset.
void ApplyZip64Extra(std::string_view extra,
                     bool need_uncompressed,
                     bool need_compressed,
                     bool need_offset,
                     uint64_t* uncompressed,
                     uint64_t* compressed,
                     uint64_t* offset,
                     std::string_view source) {
  size_t pos = 0;
  while (pos + 4 <= extra.size()) {
    const uint16_t id = Le16(extra.data() + pos);
    const uint16_t size = Le16(extra.data() + pos + 2);
    if (pos + 4 + size > extra.size()) {
      throw IoError(fmt::format("{}: extra field overruns its record", source));
    }
    if (id == kZip64ExtraId) {
      const char* p = extra.data() + pos + 4;
      size_t avail = size;
      auto take = [&](uint64_t* value) {
        if (avail < 8) {
          throw IoError(fmt::format("{}: ZIP64 extra field too short", source));
        }
        *value = Le64(p);
        p += 8;
        avail -= 8;
      };
      if (need_uncompressed) take(uncompressed);
      if (need_compressed) take(compressed);
      if (need_offset) take(offset);
      return;
    }
    pos += 4 + size;
  }
  if (need_uncompressed || need_compressed || need_offset) {
    throw IoError(fmt::format(
        "{}: sizes are 0xFFFFFFFF but no ZIP64 extra field is present",
        source));
  }
}

}  // namespace

// ---------------------------------------------------------------------------
// Reading.

ZipReader::ZipReader(std::string bytes, std::string source)
    : bytes_(std::move(bytes)), source_(std::move(source)) {
  const std::string& file = source_;
  const size_t n = bytes_.size();
  if (n < kEndOfCentralDirSize) {
    throw IoError(fmt::format(
        "{}: not a zip archive ({} bytes, too short for an end record)",
        file,
        n));
  }
  // The end-of-central-directory record sits in the last 22 + 65535 bytes.
  size_t eocd = std::string::npos;
  const size_t lowest =
      n > kEndOfCentralDirSize + kMax16 ? n - kEndOfCentralDirSize - kMax16 : 0;
  for (size_t pos = n - kEndOfCentralDirSize + 1; pos-- > lowest;) {
    if (Le32(bytes_.data() + pos) == kEndOfCentralDirSignature) {
      eocd = pos;
      break;
    }
  }
  if (eocd == std::string::npos) {
    if (n >= 4 && Le32(bytes_.data()) == kLocalHeaderSignature) {
      throw IoError(fmt::format(
          "{}: truncated zip archive (no end-of-central-directory record)",
          file));
    }
    throw IoError(fmt::format(
        "{}: not a zip archive (no end-of-central-directory record)", file));
  }
  const char* e = bytes_.data() + eocd;
  uint64_t num_entries = Le16(e + 10);
  uint64_t cd_size = Le32(e + 12);
  uint64_t cd_offset = Le32(e + 16);
  if (num_entries == kMax16 || cd_size == kMax32 || cd_offset == kMax32) {
    if (eocd < kZip64LocatorSize ||
        Le32(bytes_.data() + eocd - kZip64LocatorSize) !=
            kZip64LocatorSignature) {
      throw IoError(fmt::format(
          "{}: ZIP64 end record expected but its locator is missing", file));
    }
    const uint64_t z64 = Le64(bytes_.data() + eocd - kZip64LocatorSize + 8);
    if (z64 + kZip64EndOfCentralDirSize > n ||
        Le32(bytes_.data() + z64) != kZip64EndOfCentralDirSignature) {
      throw IoError(
          fmt::format("{}: bad ZIP64 end-of-central-directory record", file));
    }
    num_entries = Le64(bytes_.data() + z64 + 32);
    cd_size = Le64(bytes_.data() + z64 + 40);
    cd_offset = Le64(bytes_.data() + z64 + 48);
  }
  if (cd_offset > n || cd_size > n - cd_offset) {
    throw IoError(
        fmt::format("{}: truncated zip archive (central directory at {} + {} "
                    "bytes, file has {})",
                    file,
                    cd_offset,
                    cd_size,
                    n));
  }
  size_t pos = cd_offset;
  const size_t cd_end = cd_offset + cd_size;
  for (uint64_t i = 0; i < num_entries; ++i) {
    if (pos + kCentralHeaderSize > cd_end ||
        Le32(bytes_.data() + pos) != kCentralHeaderSignature) {
      throw IoError(
          fmt::format("{}: corrupt zip central directory (entry {} of {})",
                      file,
                      i,
                      num_entries));
    }
    const char* c = bytes_.data() + pos;
    ZipEntry entry;
    entry.flags = Le16(c + 8);
    entry.method = Le16(c + 10);
    entry.crc32 = Le32(c + 16);
    const uint32_t csize32 = Le32(c + 20);
    const uint32_t usize32 = Le32(c + 24);
    const uint16_t name_len = Le16(c + 28);
    const uint16_t extra_len = Le16(c + 30);
    const uint16_t comment_len = Le16(c + 32);
    const uint32_t offset32 = Le32(c + 42);
    if (pos + kCentralHeaderSize + name_len + extra_len + comment_len >
        cd_end) {
      throw IoError(fmt::format(
          "{}: corrupt zip central directory (entry {} overruns it)", file, i));
    }
    entry.name.assign(c + kCentralHeaderSize, name_len);
    entry.compressed_size = csize32;
    entry.uncompressed_size = usize32;
    entry.local_header_offset = offset32;
    ApplyZip64Extra(
        std::string_view(c + kCentralHeaderSize + name_len, extra_len),
        usize32 == kMax32,
        csize32 == kMax32,
        offset32 == kMax32,
        &entry.uncompressed_size,
        &entry.compressed_size,
        &entry.local_header_offset,
        fmt::format("{}: entry '{}'", file, entry.name));
    pos += kCentralHeaderSize + name_len + extra_len + comment_len;
    entries_.push_back(std::move(entry));
  }
}

std::string ZipReader::Read(const ZipEntry& entry) const {
  const std::string source = fmt::format("{}: entry '{}'", source_, entry.name);
  if (entry.flags & 0x1) {
    throw IoError(
        fmt::format("{}: encrypted zip members are not supported", source));
  }
  const uint64_t offset = entry.local_header_offset;
  if (offset > bytes_.size() || bytes_.size() - offset < kLocalHeaderSize ||
      Le32(bytes_.data() + offset) != kLocalHeaderSignature) {
    throw IoError(
        fmt::format("{}: bad local header at offset {} (truncated or corrupt)",
                    source,
                    offset));
  }
  const char* l = bytes_.data() + offset;
  const uint64_t data_start = offset + kLocalHeaderSize + Le16(l + 26) +
                              static_cast<uint64_t>(Le16(l + 28));
  if (data_start > bytes_.size() ||
      bytes_.size() - data_start < entry.compressed_size) {
    throw IoError(fmt::format(
        "{}: truncated ({} bytes of data declared at offset {}, file has {})",
        source,
        entry.compressed_size,
        data_start,
        bytes_.size()));
  }
  const std::string_view raw(bytes_.data() + data_start, entry.compressed_size);
  std::string data;
  if (entry.method == 0) {
    if (entry.compressed_size != entry.uncompressed_size) {
      throw IoError(
          fmt::format("{}: stored member with compressed size {} != size {}",
                      source,
                      entry.compressed_size,
                      entry.uncompressed_size));
    }
    data = std::string(raw);
  } else if (entry.method == 8) {
    // Deflate cannot expand data more than ~1032:1; a larger declared size is
    // corruption (and must not drive the allocation below).
    if (entry.uncompressed_size >
        kMaxDeflateRatio * entry.compressed_size + 1024) {
      throw IoError(
          fmt::format("{}: declares {} bytes from {} deflated bytes, more than "
                      "deflate can produce "
                      "(corrupt directory)",
                      source,
                      entry.uncompressed_size,
                      entry.compressed_size));
    }
    data = InflateRaw(raw, entry.uncompressed_size, source);
  } else {
    throw IoError(
        fmt::format("{}: unsupported zip compression method {} (expected 0 "
                    "stored or 8 deflate)",
                    source,
                    entry.method));
  }
  const uint32_t crc = Crc32(data);
  if (crc != entry.crc32) {
    throw IoError(fmt::format(
        "{}: CRC-32 mismatch (stored {:08x}, computed {:08x}): corrupt data",
        source,
        entry.crc32,
        crc));
  }
  return data;
}

// ---------------------------------------------------------------------------
// Writing.

ZipWriter::ZipWriter(std::ostream& out, ZipWriteOptions options)
    : out_(out), options_(options) {}

void ZipWriter::Add(std::string_view name, std::string_view bytes) {
  if (name.size() > kMax16) {
    throw IoError(fmt::format(
        "zip member name of {} bytes is longer than 65535", name.size()));
  }
  const uint32_t crc = Crc32(bytes);
  std::string deflated;
  if (options_.deflate) deflated = DeflateRaw(bytes);
  std::string_view payload = bytes;
  if (options_.deflate) payload = deflated;
  const uint16_t method = options_.deflate ? 8 : 0;
  const uint64_t usize = bytes.size();
  const uint64_t csize = payload.size();
  const bool sizes64 =
      options_.force_zip64 || usize >= kMax32 || csize >= kMax32;
  const bool offset64 = options_.force_zip64 || offset_ >= kMax32;
  const uint16_t version = (sizes64 || offset64) ? 45 : 20;

  std::string local;
  Put32(local, kLocalHeaderSignature);
  Put16(local, version);
  Put16(local, 0);  // flags
  Put16(local, method);
  Put16(local, kDosTime);
  Put16(local, kDosDate);
  Put32(local, crc);
  Put32(local, sizes64 ? kMax32 : static_cast<uint32_t>(csize));
  Put32(local, sizes64 ? kMax32 : static_cast<uint32_t>(usize));
  Put16(local, static_cast<uint16_t>(name.size()));
  Put16(local, sizes64 ? 20 : 0);
  local += name;
  if (sizes64) {
    Put16(local, kZip64ExtraId);
    Put16(local, 16);
    Put64(local, usize);
    Put64(local, csize);
  }
  out_.write(local.data(), static_cast<std::streamsize>(local.size()));
  out_.write(payload.data(), static_cast<std::streamsize>(payload.size()));

  std::string extra;
  if (sizes64 || offset64) {
    std::string fields;
    if (sizes64) {
      Put64(fields, usize);
      Put64(fields, csize);
    }
    if (offset64) Put64(fields, offset_);
    Put16(extra, kZip64ExtraId);
    Put16(extra, static_cast<uint16_t>(fields.size()));
    extra += fields;
  }
  Put32(central_, kCentralHeaderSignature);
  Put16(central_, version);  // made by (MS-DOS, spec version)
  Put16(central_, version);  // needed
  Put16(central_, 0);
  Put16(central_, method);
  Put16(central_, kDosTime);
  Put16(central_, kDosDate);
  Put32(central_, crc);
  Put32(central_, sizes64 ? kMax32 : static_cast<uint32_t>(csize));
  Put32(central_, sizes64 ? kMax32 : static_cast<uint32_t>(usize));
  Put16(central_, static_cast<uint16_t>(name.size()));
  Put16(central_, static_cast<uint16_t>(extra.size()));
  Put16(central_, 0);            // comment
  Put16(central_, 0);            // disk
  Put16(central_, 0);            // internal attributes
  Put32(central_, 0x81A40000u);  // external attributes: regular file, 0644
  Put32(central_, offset64 ? kMax32 : static_cast<uint32_t>(offset_));
  central_ += name;
  central_ += extra;
  offset_ += local.size() + payload.size();
  ++num_entries_;
}

void ZipWriter::Finish() {
  const uint64_t cd_offset = offset_;
  const uint64_t cd_size = central_.size();
  const uint64_t num_entries = num_entries_;
  const bool end64 = options_.force_zip64 || num_entries >= kMax16 ||
                     cd_offset >= kMax32 || cd_size >= kMax32;
  std::string tail = central_;
  if (end64) {
    const uint64_t z64_offset = cd_offset + cd_size;
    Put32(tail, kZip64EndOfCentralDirSignature);
    Put64(tail, kZip64EndOfCentralDirSize - 12);
    Put16(tail, 45);
    Put16(tail, 45);
    Put32(tail, 0);
    Put32(tail, 0);
    Put64(tail, num_entries);
    Put64(tail, num_entries);
    Put64(tail, cd_size);
    Put64(tail, cd_offset);
    Put32(tail, kZip64LocatorSignature);
    Put32(tail, 0);
    Put64(tail, z64_offset);
    Put32(tail, 1);
  }
  Put32(tail, kEndOfCentralDirSignature);
  Put16(tail, 0);
  Put16(tail, 0);
  Put16(tail, end64 ? kMax16 : static_cast<uint16_t>(num_entries));
  Put16(tail, end64 ? kMax16 : static_cast<uint16_t>(num_entries));
  Put32(tail, end64 ? kMax32 : static_cast<uint32_t>(cd_size));
  Put32(tail, end64 ? kMax32 : static_cast<uint32_t>(cd_offset));
  Put16(tail, 0);
  out_.write(tail.data(), static_cast<std::streamsize>(tail.size()));
}

// ---------------------------------------------------------------------------
// gzip.

std::string Gunzip(std::string_view compressed, std::string_view source) {
  if (compressed.empty()) {
    throw IoError(fmt::format("{}: empty file is not a gzip stream", source));
  }
  std::string out;
  z_stream stream{};
  if (inflateInit2(&stream, 32 + MAX_WBITS) != Z_OK) {
    throw IoError(fmt::format("{}: zlib inflateInit2 failed", source));
  }
  std::vector<char> buffer(1 << 16);
  size_t in_offset = 0;
  while (true) {
    const size_t in_chunk = std::min(kZlibChunk, compressed.size() - in_offset);
    stream.next_in = reinterpret_cast<Bytef*>(
        const_cast<char*>(compressed.data() + in_offset));
    stream.avail_in = static_cast<uInt>(in_chunk);
    stream.next_out = reinterpret_cast<Bytef*>(buffer.data());
    stream.avail_out = static_cast<uInt>(buffer.size());
    const int status = inflate(&stream, Z_NO_FLUSH);
    const size_t consumed = in_chunk - stream.avail_in;
    const size_t produced = buffer.size() - stream.avail_out;
    in_offset += consumed;
    out.append(buffer.data(), produced);
    if (status == Z_STREAM_END) {
      // Another gzip member may follow (concatenated .gz files).
      const bool more =
          compressed.size() - in_offset >= 2 &&
          static_cast<unsigned char>(compressed[in_offset]) == 0x1f &&
          static_cast<unsigned char>(compressed[in_offset + 1]) == 0x8b;
      if (!more) break;
      inflateReset(&stream);
      continue;
    }
    if (status != Z_OK && status != Z_BUF_ERROR) {
      const std::string message = stream.msg ? stream.msg : "unknown error";
      inflateEnd(&stream);
      throw IoError(
          fmt::format("{}: corrupt gzip stream ({})", source, message));
    }
    if (consumed == 0 && produced == 0) {
      inflateEnd(&stream);
      throw IoError(fmt::format("{}: truncated gzip stream", source));
    }
  }
  inflateEnd(&stream);
  return out;
}

std::string ReadGzipFile(const std::filesystem::path& path) {
  return Gunzip(ReadFile(path), path.string());
}

}  // namespace soma
