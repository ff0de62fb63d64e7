#include "framework/io/zip.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <algorithm>
#include <ctime>
#include <deque>
#include <mutex>
#include <utility>
#include <zip.h>
#include <zlib.h>

namespace soma {
namespace {

// zlib's inflate takes at most 4 GiB per call.
constexpr size_t kZlibChunk = size_t{1} << 30;

// libzip's description of `error`, then releases it.
std::string TakeMessage(zip_error_t* error) {
  std::string message = zip_error_strerror(error);
  zip_error_fini(error);
  return message;
}

// What went wrong reading a member, from libzip's error code.
std::string DescribeReadError(int code, const std::string& libzip_message) {
  switch (code) {
    case ZIP_ER_CRC:
      return "CRC-32 mismatch (corrupt data)";
    case ZIP_ER_ZLIB:
    case ZIP_ER_COMPRESSED_DATA:
      return fmt::format("corrupt deflate stream ({})", libzip_message);
    case ZIP_ER_EOF:
      return "truncated member data";
    case ZIP_ER_COMPNOTSUPP:
      return fmt::format("unsupported compression method ({})", libzip_message);
    case ZIP_ER_ENCRNOTSUPP:
    case ZIP_ER_NOPASSWD:
    case ZIP_ER_WRONGPASSWD:
      return fmt::format("encrypted member, not supported ({})",
                         libzip_message);
    default:
      return libzip_message;
  }
}

// 1980-01-01 00:00 local time: the earliest DOS timestamp, which libzip
// converts back to 1980-01-01 00:00 (stable bytes on any machine).
time_t FixedMtime() {
  std::tm tm{};
  tm.tm_year = 80;
  tm.tm_mon = 0;
  tm.tm_mday = 1;
  tm.tm_isdst = -1;
  return std::mktime(&tm);
}

}  // namespace

// ---------------------------------------------------------------------------
// Reading.

struct ZipReader::Impl {
  std::string bytes;  // the archive; libzip reads it in place
  zip_t* archive = nullptr;
  std::mutex mutex;  // libzip archives are not thread-safe

  ~Impl() {
    if (archive != nullptr) zip_discard(archive);
  }
};

ZipReader::ZipReader(std::string bytes, std::string source)
    : impl_(std::make_unique<Impl>()), source_(std::move(source)) {
  impl_->bytes = std::move(bytes);
  zip_error_t error;
  zip_error_init(&error);
  zip_source_t* data = zip_source_buffer_create(
      impl_->bytes.data(), impl_->bytes.size(), 0, &error);
  if (data == nullptr) {
    throw IoError(fmt::format(
        "{}: cannot read zip archive: {}", source_, TakeMessage(&error)));
  }
  impl_->archive =
      zip_open_from_source(data, ZIP_RDONLY | ZIP_CHECKCONS, &error);
  if (impl_->archive == nullptr) {
    zip_source_free(data);
    const int code = zip_error_code_zip(&error);
    const std::string message = TakeMessage(&error);
    // libzip reports both a file cut short (no end-of-central-directory
    // record) and an end record that points at no valid central directory
    // as "not a zip archive"; a file starting with a local file header is
    // one of those two.
    const std::string_view bytes_view(impl_->bytes);
    const bool starts_like_zip = bytes_view.substr(0, 4) == "PK\x03\x04";
    if (code == ZIP_ER_NOZIP && starts_like_zip) {
      // The end record sits in the last 22 + 65535 (comment) bytes.
      const size_t tail = std::min<size_t>(bytes_view.size(), 22 + 0xFFFF);
      if (bytes_view.substr(bytes_view.size() - tail).find("PK\x05\x06") ==
          std::string_view::npos) {
        throw IoError(fmt::format(
            "{}: truncated zip archive (starts with a zip member but has no "
            "end-of-central-directory record)",
            source_));
      }
      throw IoError(fmt::format(
          "{}: corrupt zip archive (the end-of-central-directory record does "
          "not lead to a valid central directory)",
          source_));
    }
    if (code == ZIP_ER_NOZIP)
      throw IoError(fmt::format("{}: not a zip archive", source_));
    if (code == ZIP_ER_INCONS) {
      throw IoError(fmt::format(
          "{}: corrupt or truncated zip archive ({})", source_, message));
    }
    throw IoError(
        fmt::format("{}: cannot open zip archive: {}", source_, message));
  }
  const zip_int64_t count = zip_get_num_entries(impl_->archive, 0);
  for (zip_int64_t i = 0; i < count; ++i) {
    zip_stat_t stat;
    zip_stat_init(&stat);
    if (zip_stat_index(
            impl_->archive, static_cast<zip_uint64_t>(i), 0, &stat) != 0) {
      throw IoError(fmt::format("{}: corrupt zip archive (member {}: {})",
                                source_,
                                i,
                                zip_strerror(impl_->archive)));
    }
    ZipEntry entry;
    entry.name = stat.name != nullptr ? stat.name : "";
    entry.index = static_cast<uint64_t>(i);
    entry.method = static_cast<uint16_t>(stat.comp_method);
    entry.crc32 = stat.crc;
    entry.compressed_size = stat.comp_size;
    entry.uncompressed_size = stat.size;
    entries_.push_back(std::move(entry));
  }
}

ZipReader::~ZipReader() = default;
ZipReader::ZipReader(ZipReader&&) noexcept = default;
ZipReader& ZipReader::operator=(ZipReader&&) noexcept = default;

std::string ZipReader::Read(const ZipEntry& entry) const {
  const std::lock_guard<std::mutex> lock(impl_->mutex);
  const auto fail = [&](const std::string& what) {
    throw IoError(fmt::format("{}: entry '{}': {}", source_, entry.name, what));
  };
  zip_file_t* file = zip_fopen_index(impl_->archive, entry.index, 0);
  if (file == nullptr) {
    zip_error_t* error = zip_get_error(impl_->archive);
    const std::string what =
        DescribeReadError(zip_error_code_zip(error), zip_error_strerror(error));
    zip_error_clear(impl_->archive);
    fail(what);
  }
  std::string out(entry.uncompressed_size, '\0');
  size_t done = 0;
  char extra = 0;
  while (true) {
    // Read until libzip reports the end: only then has it checked the CRC.
    const bool full = done >= out.size();
    const zip_int64_t n = zip_fread(
        file, full ? &extra : out.data() + done, full ? 1 : out.size() - done);
    if (n < 0) {
      zip_error_t* error = zip_file_get_error(file);
      const std::string what = DescribeReadError(zip_error_code_zip(error),
                                                 zip_error_strerror(error));
      zip_fclose(file);
      fail(what);
    }
    if (n == 0) break;
    if (full) {
      zip_fclose(file);
      fail(fmt::format("more data than the {} bytes the directory declares",
                       out.size()));
    }
    done += static_cast<size_t>(n);
  }
  zip_fclose(file);
  if (done != out.size()) {
    fail(fmt::format(
        "truncated member data ({} of {} bytes)", done, out.size()));
  }
  return out;
}

// ---------------------------------------------------------------------------
// Writing.

struct ZipWriter::Impl {
  zip_source_t* buffer = nullptr;  // the archive being built (kept)
  zip_t* archive = nullptr;
  std::deque<std::string> contents;  // member bytes, alive until zip_close
  bool finished = false;

  ~Impl() {
    if (archive != nullptr) zip_discard(archive);
    if (buffer != nullptr) zip_source_free(buffer);
  }
};

ZipWriter::ZipWriter(std::ostream& out, ZipWriteOptions options)
    : out_(out), options_(options), impl_(std::make_unique<Impl>()) {
  zip_error_t error;
  zip_error_init(&error);
  impl_->buffer = zip_source_buffer_create(nullptr, 0, 0, &error);
  if (impl_->buffer == nullptr) {
    throw IoError(fmt::format("cannot create an in-memory zip archive: {}",
                              TakeMessage(&error)));
  }
  zip_source_keep(impl_->buffer);  // read it back after zip_close
  impl_->archive = zip_open_from_source(impl_->buffer, ZIP_TRUNCATE, &error);
  if (impl_->archive == nullptr) {
    zip_source_free(impl_->buffer);  // the failed open's reference
    throw IoError(fmt::format("cannot create an in-memory zip archive: {}",
                              TakeMessage(&error)));
  }
  zip_error_fini(&error);
}

ZipWriter::~ZipWriter() = default;

void ZipWriter::Add(std::string_view name, std::string_view bytes) {
  SOMA_CHECK(!impl_->finished) << "ZipWriter::Add after Finish";
  if (name.empty() || name.size() > 0xFFFF) {
    throw IoError(fmt::format(
        "zip member name of {} bytes (expected 1 to 65535)", name.size()));
  }
  const std::string& data = impl_->contents.emplace_back(bytes);
  zip_source_t* source =
      zip_source_buffer(impl_->archive, data.data(), data.size(), 0);
  if (source == nullptr) {
    throw IoError(
        fmt::format("zip member '{}': {}", name, zip_strerror(impl_->archive)));
  }
  const zip_int64_t index = zip_file_add(
      impl_->archive, std::string(name).c_str(), source, ZIP_FL_ENC_GUESS);
  if (index < 0) {
    zip_source_free(source);
    throw IoError(
        fmt::format("zip member '{}': {}", name, zip_strerror(impl_->archive)));
  }
  const auto member = static_cast<zip_uint64_t>(index);
  if (zip_set_file_compression(impl_->archive,
                               member,
                               options_.deflate ? ZIP_CM_DEFLATE : ZIP_CM_STORE,
                               0) != 0 ||
      zip_file_set_mtime(impl_->archive, member, FixedMtime(), 0) != 0) {
    throw IoError(
        fmt::format("zip member '{}': {}", name, zip_strerror(impl_->archive)));
  }
}

void ZipWriter::Finish() {
  SOMA_CHECK(!impl_->finished) << "ZipWriter::Finish called twice";
  impl_->finished = true;
  const bool empty = zip_get_num_entries(impl_->archive, 0) == 0;
  if (zip_close(impl_->archive) != 0) {
    const std::string message = zip_strerror(impl_->archive);
    throw IoError(fmt::format("cannot write zip archive: {}", message));
  }
  impl_->archive = nullptr;
  if (empty) {
    // libzip writes nothing for an archive without members; write the
    // 22-byte end-of-central-directory record of an empty archive, as
    // Python's zipfile and numpy.savez do.
    const char kEmptyArchive[22] = {'P', 'K', 5, 6};
    out_.write(kEmptyArchive, sizeof(kEmptyArchive));
    return;
  }
  if (zip_source_open(impl_->buffer) != 0) {
    throw IoError(
        fmt::format("cannot read back the zip archive: {}",
                    zip_error_strerror(zip_source_error(impl_->buffer))));
  }
  std::vector<char> chunk(size_t{1} << 16);
  while (true) {
    const zip_int64_t n =
        zip_source_read(impl_->buffer, chunk.data(), chunk.size());
    if (n < 0) {
      zip_source_close(impl_->buffer);
      throw IoError(
          fmt::format("cannot read back the zip archive: {}",
                      zip_error_strerror(zip_source_error(impl_->buffer))));
    }
    if (n == 0) break;
    out_.write(chunk.data(), static_cast<std::streamsize>(n));
  }
  zip_source_close(impl_->buffer);
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
