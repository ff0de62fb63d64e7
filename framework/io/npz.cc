#include "framework/io/npz.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>
#include <utility>
#include <zlib.h>

namespace soma {
namespace {

static_assert(
    std::endian::native == std::endian::little,
    "npz.cc assumes a little-endian host (NpyArray::data is little-endian)");

constexpr char kNpyMagic[] = "\x93NUMPY";
constexpr size_t kNpyMagicSize = 6;

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

uint16_t Le16(const char* p) {
  uint16_t v;
  std::memcpy(&v, p, 2);
  return v;
}
uint32_t Le32(const char* p) {
  uint32_t v;
  std::memcpy(&v, p, 4);
  return v;
}
uint64_t Le64(const char* p) {
  uint64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

void Put16(std::string& out, uint16_t v) {
  out.append(reinterpret_cast<const char*>(&v), 2);
}
void Put32(std::string& out, uint32_t v) {
  out.append(reinterpret_cast<const char*>(&v), 4);
}
void Put64(std::string& out, uint64_t v) {
  out.append(reinterpret_cast<const char*>(&v), 8);
}

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
// dtype descriptors.

struct Dtype {
  char kind = 'f';    // b i u f U S
  int item_size = 8;  // bytes per element
  bool big_endian = false;
};

// Parses a descr string ("<f8", "|u1", ">i4", "<U6", "|S3", "=f4").
Dtype ParseDescr(std::string_view descr, std::string_view source) {
  const std::string supported =
      "supported: |b1 |i1 |u1 <i2 <u2 <i4 <u4 <i8 <u8 <f4 <f8 <U<n> |S<n>";
  if (descr.empty()) {
    throw IoError(
        fmt::format("{}: empty dtype descriptor ({})", source, supported));
  }
  std::string_view rest = descr;
  Dtype dtype;
  const char order = rest.front();
  if (order == '<' || order == '>' || order == '|' || order == '=') {
    dtype.big_endian = order == '>';
    rest.remove_prefix(1);
  }
  if (rest.empty()) {
    throw IoError(
        fmt::format("{}: malformed dtype '{}' ({})", source, descr, supported));
  }
  dtype.kind = rest.front();
  rest.remove_prefix(1);
  if (dtype.kind == 'O') {
    throw IoError(
        fmt::format("{}: unsupported dtype '{}' (object arrays are pickled "
                    "Python objects; {})",
                    source,
                    descr,
                    supported));
  }
  if (dtype.kind == '?') {  // numpy's one-character bool code
    dtype.kind = 'b';
    if (rest.empty()) rest = "1";
  }
  int64_t size = 0;
  if (rest.empty()) {
    throw IoError(fmt::format(
        "{}: unsupported dtype '{}' ({})", source, descr, supported));
  }
  for (const char c : rest) {
    if (c < '0' || c > '9' || size > 1'000'000) {
      throw IoError(fmt::format(
          "{}: unsupported dtype '{}' ({})", source, descr, supported));
    }
    size = size * 10 + (c - '0');
  }
  bool ok = false;
  switch (dtype.kind) {
    case 'b':
      ok = size == 1;
      break;
    case 'i':
    case 'u':
      ok = size == 1 || size == 2 || size == 4 || size == 8;
      break;
    case 'f':
      ok = size == 4 || size == 8;
      break;
    case 'U':
      ok = size >= 1;
      size *= 4;
      break;
    case 'S':
      ok = size >= 1;
      break;
    default:
      ok = false;
  }
  if (!ok) {
    throw IoError(fmt::format(
        "{}: unsupported dtype '{}' ({})", source, descr, supported));
  }
  dtype.item_size = static_cast<int>(size);
  return dtype;
}

std::string NormalizedDescr(const Dtype& dtype) {
  const bool one_byte = dtype.kind == 'S' || dtype.item_size == 1;
  const int count = dtype.kind == 'U' ? dtype.item_size / 4 : dtype.item_size;
  return fmt::format("{}{}{}", one_byte ? '|' : '<', dtype.kind, count);
}

Dtype DtypeOf(const NpyArray& array) {
  return ParseDescr(array.dtype, "NpyArray");
}

// ---------------------------------------------------------------------------
// The .npy header: a Python dict literal.

struct PyValue {
  enum class Type { kString, kBool, kInt, kNone, kTuple, kList, kDict };
  Type type = Type::kNone;
  std::string text;
  bool boolean = false;
  int64_t integer = 0;
  std::vector<PyValue> items;     // tuple / list elements, dict values
  std::vector<std::string> keys;  // dict keys, parallel to `items`
};

class PyLiteralParser {
 public:
  PyLiteralParser(std::string_view text, std::string_view source)
      : text_(text), source_(source) {}

  PyValue ParseDocument() {
    PyValue value = ParseValue(0);
    SkipSpace();
    if (pos_ != text_.size()) Fail("trailing characters after the header dict");
    return value;
  }

 private:
  [[noreturn]] void Fail(std::string_view what) const {
    throw IoError(
        fmt::format("{}: malformed .npy header at column {}: {} (header: {})",
                    source_,
                    pos_ + 1,
                    what,
                    Escaped()));
  }

  std::string Escaped() const {
    std::string out;
    for (const char c : text_.substr(0, 200)) {
      if (c == '\n') {
        out += "\\n";
      } else if (static_cast<unsigned char>(c) < 0x20) {
        out += '?';
      } else {
        out += c;
      }
    }
    return out;
  }

  void SkipSpace() {
    while (pos_ < text_.size() &&
           (text_[pos_] == ' ' || text_[pos_] == '\t' || text_[pos_] == '\n' ||
            text_[pos_] == '\r')) {
      ++pos_;
    }
  }

  bool Consume(char c) {
    SkipSpace();
    if (pos_ < text_.size() && text_[pos_] == c) {
      ++pos_;
      return true;
    }
    return false;
  }

  PyValue ParseValue(int depth) {
    if (depth > 16) Fail("nesting too deep");
    SkipSpace();
    if (pos_ >= text_.size()) Fail("unexpected end");
    const char c = text_[pos_];
    if (c == '\'' || c == '"') return ParseString();
    if (c == '(' || c == '[') return ParseSequence(depth);
    if (c == '{') return ParseDict(depth);
    if (c == '-' || c == '+' || (c >= '0' && c <= '9')) return ParseInt();
    for (const auto& [word, type, flag] :
         {std::tuple<std::string_view, PyValue::Type, bool>{
              "True", PyValue::Type::kBool, true},
          {"False", PyValue::Type::kBool, false},
          {"None", PyValue::Type::kNone, false}}) {
      if (text_.substr(pos_, word.size()) == word) {
        pos_ += word.size();
        PyValue value;
        value.type = type;
        value.boolean = flag;
        return value;
      }
    }
    Fail(fmt::format("unexpected character '{}'", c));
  }

  PyValue ParseString() {
    const char quote = text_[pos_++];
    PyValue value;
    value.type = PyValue::Type::kString;
    while (pos_ < text_.size() && text_[pos_] != quote) {
      if (text_[pos_] == '\\' && pos_ + 1 < text_.size()) ++pos_;
      value.text += text_[pos_++];
    }
    if (pos_ >= text_.size()) Fail("unterminated string");
    ++pos_;
    return value;
  }

  PyValue ParseInt() {
    PyValue value;
    value.type = PyValue::Type::kInt;
    bool negative = false;
    if (text_[pos_] == '-' || text_[pos_] == '+')
      negative = text_[pos_++] == '-';
    const size_t start = pos_;
    int64_t v = 0;
    while (pos_ < text_.size() && text_[pos_] >= '0' && text_[pos_] <= '9') {
      if (v > (std::numeric_limits<int64_t>::max() - 9) / 10)
        Fail("integer too large");
      v = v * 10 + (text_[pos_++] - '0');
    }
    if (pos_ == start) Fail("expected digits");
    if (pos_ < text_.size() && (text_[pos_] == 'L' || text_[pos_] == 'l'))
      ++pos_;  // Python 2
    value.integer = negative ? -v : v;
    return value;
  }

  PyValue ParseSequence(int depth) {
    const char open = text_[pos_++];
    const char close = open == '(' ? ')' : ']';
    PyValue value;
    value.type = open == '(' ? PyValue::Type::kTuple : PyValue::Type::kList;
    if (Consume(close)) return value;
    while (true) {
      value.items.push_back(ParseValue(depth + 1));
      if (Consume(close)) return value;
      if (!Consume(',')) Fail(fmt::format("expected ',' or '{}'", close));
      if (Consume(close)) return value;
    }
  }

  PyValue ParseDict(int depth) {
    ++pos_;
    PyValue value;
    value.type = PyValue::Type::kDict;
    if (Consume('}')) return value;
    while (true) {
      SkipSpace();
      if (pos_ >= text_.size() || (text_[pos_] != '\'' && text_[pos_] != '"')) {
        Fail("expected a quoted key");
      }
      std::string key = ParseString().text;
      if (!Consume(':')) Fail("expected ':'");
      value.keys.push_back(std::move(key));
      value.items.push_back(ParseValue(depth + 1));
      if (Consume('}')) return value;
      if (!Consume(',')) Fail("expected ',' or '}'");
      if (Consume('}')) return value;
    }
  }

  std::string_view text_;
  std::string_view source_;
  size_t pos_ = 0;
};

int64_t CheckedProduct(const std::vector<int64_t>& shape,
                       std::string_view source) {
  int64_t n = 1;
  for (const int64_t d : shape) {
    if (d < 0) {
      throw IoError(
          fmt::format("{}: negative dimension {} in shape", source, d));
    }
    if (d != 0 && n > std::numeric_limits<int64_t>::max() / d) {
      throw IoError(fmt::format("{}: shape too large", source));
    }
    n *= d;
  }
  return n;
}

std::string FormatShape(const std::vector<int64_t>& shape) {
  if (shape.empty()) return "()";
  if (shape.size() == 1) return fmt::format("({},)", shape[0]);
  return fmt::format("({})", fmt::join(shape, ", "));
}

// Byte-swaps every `unit`-byte group in place.
void SwapBytes(std::vector<uint8_t>& data, int unit) {
  if (unit <= 1) return;
  for (size_t i = 0; i + unit <= data.size(); i += unit) {
    std::reverse(data.begin() + static_cast<std::ptrdiff_t>(i),
                 data.begin() + static_cast<std::ptrdiff_t>(i + unit));
  }
}

// Offset (in elements) of C-order element `c_index` in a Fortran-order buffer.
class FortranIndexer {
 public:
  explicit FortranIndexer(const std::vector<int64_t>& shape) : shape_(shape) {
    strides_.resize(shape.size());
    int64_t stride = 1;
    for (size_t d = 0; d < shape.size(); ++d) {
      strides_[d] = stride;
      stride *= shape[d];
    }
  }
  // Calls f(c_index, storage_index) for every element in C order.
  template <typename F>
  void ForEach(int64_t count, F&& f) const {
    std::vector<int64_t> index(shape_.size(), 0);
    int64_t storage = 0;
    for (int64_t c = 0; c < count; ++c) {
      f(c, storage);
      for (int d = static_cast<int>(shape_.size()) - 1; d >= 0; --d) {
        ++index[d];
        storage += strides_[d];
        if (index[d] < shape_[d]) break;
        storage -= strides_[d] * index[d];
        index[d] = 0;
      }
    }
  }

 private:
  std::vector<int64_t> shape_;
  std::vector<int64_t> strides_;
};

// Storage index of each C-order element (identity for C order / ndim < 2).
template <typename F>
void ForEachElement(const NpyArray& array, F&& f) {
  const int64_t count = array.num_elements();
  if (!array.fortran_order || array.shape.size() < 2) {
    for (int64_t i = 0; i < count; ++i) f(i, i);
    return;
  }
  FortranIndexer(array.shape).ForEach(count, f);
}

double ElementAsDouble(const uint8_t* p, const Dtype& dtype) {
  switch (dtype.kind) {
    case 'b':
      return *p != 0 ? 1.0 : 0.0;
    case 'f':
      if (dtype.item_size == 4) {
        float v;
        std::memcpy(&v, p, 4);
        return v;
      } else {
        double v;
        std::memcpy(&v, p, 8);
        return v;
      }
    case 'i':
      switch (dtype.item_size) {
        case 1:
          return static_cast<int8_t>(*p);
        case 2: {
          int16_t v;
          std::memcpy(&v, p, 2);
          return v;
        }
        case 4: {
          int32_t v;
          std::memcpy(&v, p, 4);
          return v;
        }
        default: {
          int64_t v;
          std::memcpy(&v, p, 8);
          return static_cast<double>(v);
        }
      }
    case 'u':
      switch (dtype.item_size) {
        case 1:
          return *p;
        case 2: {
          uint16_t v;
          std::memcpy(&v, p, 2);
          return v;
        }
        case 4: {
          uint32_t v;
          std::memcpy(&v, p, 4);
          return v;
        }
        default: {
          uint64_t v;
          std::memcpy(&v, p, 8);
          return static_cast<double>(v);
        }
      }
    default:
      return 0.0;
  }
}

void AppendUtf8(std::string& out, uint32_t cp) {
  if (cp < 0x80) {
    out += static_cast<char>(cp);
  } else if (cp < 0x800) {
    out += static_cast<char>(0xC0 | (cp >> 6));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else if (cp < 0x10000) {
    out += static_cast<char>(0xE0 | (cp >> 12));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else {
    out += static_cast<char>(0xF0 | (cp >> 18));
    out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  }
}

// Decodes UTF-8 into code points (a byte that does not start a valid
// sequence is taken as Latin-1).
std::vector<uint32_t> DecodeUtf8(std::string_view s) {
  std::vector<uint32_t> out;
  size_t i = 0;
  while (i < s.size()) {
    const auto c = static_cast<unsigned char>(s[i]);
    int extra = -1;
    uint32_t cp = c;
    if (c < 0x80) {
      extra = 0;
    } else if (c >= 0xC0 && c < 0xE0) {
      extra = 1;
      cp = c & 0x1F;
    } else if (c >= 0xE0 && c < 0xF0) {
      extra = 2;
      cp = c & 0x0F;
    } else if (c >= 0xF0 && c < 0xF8) {
      extra = 3;
      cp = c & 0x07;
    }
    bool valid = extra >= 0 && i + extra < s.size();
    for (int k = 1; valid && k <= extra; ++k) {
      const auto cc = static_cast<unsigned char>(s[i + k]);
      if ((cc & 0xC0) != 0x80) valid = false;
      cp = (cp << 6) | (cc & 0x3F);
    }
    if (!valid) {
      out.push_back(c);
      ++i;
    } else {
      out.push_back(cp);
      i += extra + 1;
    }
  }
  return out;
}

template <typename T>
NpyArray MakeArray(std::vector<int64_t> shape,
                   const std::vector<T>& values,
                   std::string_view descr) {
  NpyArray array;
  array.dtype = std::string(descr);
  array.shape = std::move(shape);
  const int64_t count = CheckedProduct(array.shape, "NpyArray");
  if (count != static_cast<int64_t>(values.size())) {
    throw ShapeError(
        fmt::format("NpyArray: {} values for shape {} ({} elements)",
                    values.size(),
                    FormatShape(array.shape),
                    count));
  }
  array.data.resize(values.size() * sizeof(T));
  if (!values.empty())
    std::memcpy(array.data.data(), values.data(), array.data.size());
  return array;
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

std::string EntryKey(std::string_view name) {
  constexpr std::string_view kSuffix = ".npy";
  return std::string(name.substr(0, name.size() - kSuffix.size()));
}

bool IsNpyName(std::string_view name) {
  return name.size() > 4 && name.substr(name.size() - 4) == ".npy";
}

}  // namespace

// ---------------------------------------------------------------------------
// NpyArray.

int64_t NpyArray::num_elements() const {
  return CheckedProduct(shape, "NpyArray");
}

int NpyArray::item_size() const { return DtypeOf(*this).item_size; }

char NpyArray::kind() const { return DtypeOf(*this).kind; }

std::string NpyArray::ShapeString() const { return FormatShape(shape); }

std::vector<double> NpyArray::AsDoubles() const {
  const Dtype dtype = DtypeOf(*this);
  if (dtype.kind == 'U' || dtype.kind == 'S') {
    throw IoError(fmt::format(
        "NpyArray: cannot read a '{}' string array as numbers", this->dtype));
  }
  const int64_t count = num_elements();
  if (static_cast<int64_t>(data.size()) != count * dtype.item_size) {
    throw ShapeError(
        fmt::format("NpyArray: {} data bytes for {} elements of '{}'",
                    data.size(),
                    count,
                    this->dtype));
  }
  std::vector<double> out(count);
  ForEachElement(*this, [&](int64_t c, int64_t s) {
    out[c] = ElementAsDouble(data.data() + s * dtype.item_size, dtype);
  });
  return out;
}

std::vector<int64_t> NpyArray::AsInt64() const {
  const Dtype dtype = DtypeOf(*this);
  if (dtype.kind == 'U' || dtype.kind == 'S') {
    throw IoError(fmt::format(
        "NpyArray: cannot read a '{}' string array as integers", this->dtype));
  }
  const int64_t count = num_elements();
  if (static_cast<int64_t>(data.size()) != count * dtype.item_size) {
    throw ShapeError(
        fmt::format("NpyArray: {} data bytes for {} elements of '{}'",
                    data.size(),
                    count,
                    this->dtype));
  }
  std::vector<int64_t> out(count);
  ForEachElement(*this, [&](int64_t c, int64_t s) {
    const uint8_t* p = data.data() + s * dtype.item_size;
    if (dtype.kind == 'i' && dtype.item_size == 8) {
      std::memcpy(&out[c], p, 8);
    } else if (dtype.kind == 'u' && dtype.item_size == 8) {
      uint64_t v;
      std::memcpy(&v, p, 8);
      if (v > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
        throw IoError(
            fmt::format("NpyArray: uint64 value {} does not fit in int64", v));
      }
      out[c] = static_cast<int64_t>(v);
    } else {
      const double v = ElementAsDouble(p, dtype);
      if (dtype.kind == 'f' && (!std::isfinite(v) || v != std::floor(v) ||
                                std::abs(v) > 9.007199254740992e15)) {
        throw IoError(fmt::format(
            "NpyArray: '{}' value {} is not an integer", this->dtype, v));
      }
      out[c] = static_cast<int64_t>(v);
    }
  });
  return out;
}

std::vector<std::string> NpyArray::AsStrings() const {
  const Dtype dtype = DtypeOf(*this);
  if (dtype.kind != 'U' && dtype.kind != 'S') {
    throw IoError(
        fmt::format("NpyArray: '{}' is not a string dtype", this->dtype));
  }
  const int64_t count = num_elements();
  if (static_cast<int64_t>(data.size()) != count * dtype.item_size) {
    throw ShapeError(
        fmt::format("NpyArray: {} data bytes for {} elements of '{}'",
                    data.size(),
                    count,
                    this->dtype));
  }
  std::vector<std::string> out(count);
  ForEachElement(*this, [&](int64_t c, int64_t s) {
    const uint8_t* p = data.data() + s * dtype.item_size;
    std::string text;
    if (dtype.kind == 'S') {
      text.assign(reinterpret_cast<const char*>(p), dtype.item_size);
      text.erase(std::find(text.begin(), text.end(), '\0'), text.end());
    } else {
      for (int k = 0; k < dtype.item_size / 4; ++k) {
        uint32_t cp;
        std::memcpy(&cp, p + 4 * static_cast<ptrdiff_t>(k), 4);
        if (cp == 0) break;
        AppendUtf8(text, cp);
      }
    }
    out[c] = std::move(text);
  });
  return out;
}

Eigen::MatrixXd NpyArray::AsMatrix() const {
  if (shape.size() > 2) {
    throw ShapeError(fmt::format(
        "NpyArray: AsMatrix needs at most 2 dimensions, shape is {}",
        ShapeString()));
  }
  const std::vector<double> values = AsDoubles();
  const Eigen::Index rows = shape.empty() ? 1 : shape[0];
  const Eigen::Index cols = shape.size() == 2 ? shape[1] : 1;
  Eigen::MatrixXd matrix(rows, cols);
  for (Eigen::Index r = 0; r < rows; ++r) {
    for (Eigen::Index c = 0; c < cols; ++c) matrix(r, c) = values[r * cols + c];
  }
  return matrix;
}

NpyArray NpyArray::FromDoubles(std::vector<int64_t> shape,
                               const std::vector<double>& values) {
  return MakeArray(std::move(shape), values, "<f8");
}
NpyArray NpyArray::FromFloats(std::vector<int64_t> shape,
                              const std::vector<float>& values) {
  return MakeArray(std::move(shape), values, "<f4");
}
NpyArray NpyArray::FromInt64(std::vector<int64_t> shape,
                             const std::vector<int64_t>& values) {
  return MakeArray(std::move(shape), values, "<i8");
}
NpyArray NpyArray::FromInt32(std::vector<int64_t> shape,
                             const std::vector<int32_t>& values) {
  return MakeArray(std::move(shape), values, "<i4");
}
NpyArray NpyArray::FromUInt32(std::vector<int64_t> shape,
                              const std::vector<uint32_t>& values) {
  return MakeArray(std::move(shape), values, "<u4");
}
NpyArray NpyArray::FromUInt8(std::vector<int64_t> shape,
                             const std::vector<uint8_t>& values) {
  return MakeArray(std::move(shape), values, "|u1");
}
NpyArray NpyArray::FromBools(std::vector<int64_t> shape,
                             const std::vector<bool>& values) {
  std::vector<uint8_t> bytes(values.begin(), values.end());
  return MakeArray(std::move(shape), bytes, "|b1");
}

NpyArray NpyArray::FromStrings(std::vector<int64_t> shape,
                               const std::vector<std::string>& values) {
  std::vector<std::vector<uint32_t>> decoded;
  decoded.reserve(values.size());
  size_t width = 1;
  for (const std::string& value : values) {
    decoded.push_back(DecodeUtf8(value));
    width = std::max(width, decoded.back().size());
  }
  NpyArray array;
  array.dtype = fmt::format("<U{}", width);
  array.shape = std::move(shape);
  if (CheckedProduct(array.shape, "NpyArray") !=
      static_cast<int64_t>(values.size())) {
    throw ShapeError(fmt::format("NpyArray: {} strings for shape {}",
                                 values.size(),
                                 FormatShape(array.shape)));
  }
  std::vector<uint32_t> units(values.size() * width, 0);
  for (size_t i = 0; i < decoded.size(); ++i) {
    std::copy(decoded[i].begin(), decoded[i].end(), units.begin() + i * width);
  }
  array.data.resize(units.size() * 4);
  if (!units.empty())
    std::memcpy(array.data.data(), units.data(), array.data.size());
  return array;
}

NpyArray NpyArray::FromMatrix(const Eigen::MatrixXd& matrix) {
  std::vector<double> values(matrix.size());
  for (Eigen::Index r = 0; r < matrix.rows(); ++r) {
    for (Eigen::Index c = 0; c < matrix.cols(); ++c)
      values[r * matrix.cols() + c] = matrix(r, c);
  }
  return FromDoubles({matrix.rows(), matrix.cols()}, values);
}

// ---------------------------------------------------------------------------
// .npy.

NpyArray ParseNpy(std::string_view bytes, std::string_view source) {
  if (bytes.size() < kNpyMagicSize + 2 ||
      std::memcmp(bytes.data(), kNpyMagic, kNpyMagicSize) != 0) {
    throw IoError(fmt::format(
        "{}: not a .npy array (expected the magic \\x93NUMPY)", source));
  }
  const int major = static_cast<unsigned char>(bytes[6]);
  const int minor = static_cast<unsigned char>(bytes[7]);
  size_t header_len = 0;
  size_t header_start = 0;
  if (major == 1) {
    if (bytes.size() < 10)
      throw IoError(fmt::format("{}: truncated .npy header", source));
    header_len = Le16(bytes.data() + 8);
    header_start = 10;
  } else if (major == 2 || major == 3) {
    if (bytes.size() < 12)
      throw IoError(fmt::format("{}: truncated .npy header", source));
    header_len = Le32(bytes.data() + 8);
    header_start = 12;
  } else {
    throw IoError(fmt::format(
        "{}: unsupported .npy version {}.{} (expected 1.0, 2.0 or 3.0)",
        source,
        major,
        minor));
  }
  if (bytes.size() - header_start < header_len) {
    throw IoError(
        fmt::format("{}: truncated .npy header ({} bytes declared, {} present)",
                    source,
                    header_len,
                    bytes.size() - header_start));
  }
  const std::string_view header = bytes.substr(header_start, header_len);
  const PyValue dict = PyLiteralParser(header, source).ParseDocument();
  if (dict.type != PyValue::Type::kDict) {
    throw IoError(fmt::format("{}: .npy header is not a dict", source));
  }
  const PyValue* descr = nullptr;
  const PyValue* fortran = nullptr;
  const PyValue* shape = nullptr;
  for (size_t i = 0; i < dict.keys.size(); ++i) {
    const std::string& key = dict.keys[i];
    const PyValue& value = dict.items[i];
    if (key == "descr") {
      descr = &value;
    } else if (key == "fortran_order") {
      fortran = &value;
    } else if (key == "shape") {
      shape = &value;
    }
  }
  if (descr == nullptr || fortran == nullptr || shape == nullptr) {
    throw IoError(fmt::format(
        "{}: .npy header needs 'descr', 'fortran_order' and 'shape'", source));
  }
  if (descr->type == PyValue::Type::kList) {
    throw IoError(fmt::format(
        "{}: unsupported structured dtype (record arrays)", source));
  }
  if (descr->type != PyValue::Type::kString) {
    throw IoError(fmt::format("{}: 'descr' must be a string", source));
  }
  if (fortran->type != PyValue::Type::kBool) {
    throw IoError(
        fmt::format("{}: 'fortran_order' must be True or False", source));
  }
  if (shape->type != PyValue::Type::kTuple) {
    throw IoError(
        fmt::format("{}: 'shape' must be a tuple of integers", source));
  }
  const Dtype dtype = ParseDescr(descr->text, source);
  NpyArray array;
  array.dtype = NormalizedDescr(dtype);
  array.fortran_order = fortran->boolean;
  for (const PyValue& dim : shape->items) {
    if (dim.type != PyValue::Type::kInt || dim.integer < 0) {
      throw IoError(
          fmt::format("{}: 'shape' must hold non-negative integers", source));
    }
    array.shape.push_back(dim.integer);
  }
  const int64_t count = CheckedProduct(array.shape, source);
  if (count > std::numeric_limits<int64_t>::max() / dtype.item_size) {
    throw IoError(fmt::format(
        "{}: shape {} too large", source, FormatShape(array.shape)));
  }
  const uint64_t expected = static_cast<uint64_t>(count) * dtype.item_size;
  const std::string_view payload = bytes.substr(header_start + header_len);
  if (payload.size() != expected) {
    throw IoError(fmt::format(
        "{}: data of shape {} and dtype '{}' needs {} bytes, found {}{}",
        source,
        FormatShape(array.shape),
        array.dtype,
        expected,
        payload.size(),
        payload.size() < expected ? " (truncated)" : ""));
  }
  array.data.assign(payload.begin(), payload.end());
  if (dtype.big_endian)
    SwapBytes(array.data, dtype.kind == 'U' ? 4 : dtype.item_size);
  return array;
}

std::string SerializeNpy(const NpyArray& array) {
  const Dtype dtype = DtypeOf(array);
  const int64_t count = array.num_elements();
  if (static_cast<int64_t>(array.data.size()) != count * dtype.item_size) {
    throw ShapeError(fmt::format(
        "SerializeNpy: {} data bytes for shape {} of '{}' ({} expected)",
        array.data.size(),
        FormatShape(array.shape),
        array.dtype,
        count * dtype.item_size));
  }
  std::string header =
      fmt::format("{{'descr': '{}', 'fortran_order': {}, 'shape': {}, }}",
                  NormalizedDescr(dtype),
                  array.fortran_order ? "True" : "False",
                  FormatShape(array.shape));
  // Pad with spaces so that magic + version + length + header + '\n' is a
  // multiple of 64 bytes (numpy's alignment).
  int version = 1;
  size_t prefix = kNpyMagicSize + 2 + 2;
  if ((prefix + header.size() + 1 + 63) / 64 * 64 - prefix > 65535) {
    version = 2;
    prefix = kNpyMagicSize + 2 + 4;
  }
  const size_t total = (prefix + header.size() + 1 + 63) / 64 * 64;
  header.append(total - prefix - header.size() - 1, ' ');
  header += '\n';
  std::string out(kNpyMagic, kNpyMagicSize);
  out += static_cast<char>(version);
  out += '\0';
  if (version == 1) {
    Put16(out, static_cast<uint16_t>(header.size()));
  } else {
    Put32(out, static_cast<uint32_t>(header.size()));
  }
  out += header;
  out.append(reinterpret_cast<const char*>(array.data.data()),
             array.data.size());
  return out;
}

NpyArray ReadNpy(const std::filesystem::path& path) {
  return ParseNpy(ReadFile(path), path.string());
}

void WriteNpy(const std::filesystem::path& path, const NpyArray& array) {
  WriteFileAtomic(path, SerializeNpy(array));
}

// ---------------------------------------------------------------------------
// .npz reading.

NpzReader::NpzReader(std::filesystem::path path) : path_(std::move(path)) {
  bytes_ = ReadFile(path_);
  const std::string file = path_.string();
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
    Entry entry;
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
    if (IsNpyName(entry.name)) {
      std::string key = EntryKey(entry.name);
      if (!entries_.emplace(key, std::move(entry)).second) {
        throw IoError(fmt::format("{}: duplicate member '{}.npy'", file, key));
      }
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
  const Entry& entry = it->second;
  const std::string source =
      fmt::format("{}: entry '{}'", path_.string(), entry.name);
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
  std::string inflated;
  std::string_view npy;
  if (entry.method == 0) {
    if (entry.compressed_size != entry.uncompressed_size) {
      throw IoError(
          fmt::format("{}: stored member with compressed size {} != size {}",
                      source,
                      entry.compressed_size,
                      entry.uncompressed_size));
    }
    npy = raw;
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
    inflated = InflateRaw(raw, entry.uncompressed_size, source);
    npy = inflated;
  } else {
    throw IoError(
        fmt::format("{}: unsupported zip compression method {} (expected 0 "
                    "stored or 8 deflate)",
                    source,
                    entry.method));
  }
  const uint32_t crc = Crc32(npy);
  if (crc != entry.crc32) {
    throw IoError(fmt::format(
        "{}: CRC-32 mismatch (stored {:08x}, computed {:08x}): corrupt data",
        source,
        entry.crc32,
        crc));
  }
  return ParseNpy(npy, source);
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
  uint64_t offset = 0;
  std::string central;
  for (const auto& [key, array] : arrays) {
    if (key.empty() || key.size() > 60000) {
      throw IoError(
          fmt::format("{}: invalid array key '{}'", path.string(), key));
    }
    const std::string name = key + ".npy";
    const std::string npy = SerializeNpy(array);
    const uint32_t crc = Crc32(npy);
    std::string deflated;
    if (options.compress) deflated = DeflateRaw(npy);
    std::string_view payload = npy;
    if (options.compress) payload = deflated;
    const uint16_t method = options.compress ? 8 : 0;
    const uint64_t usize = npy.size();
    const uint64_t csize = payload.size();
    const bool sizes64 =
        options.force_zip64 || usize >= kMax32 || csize >= kMax32;
    const bool offset64 = options.force_zip64 || offset >= kMax32;
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
    out.write(local.data(), static_cast<std::streamsize>(local.size()));
    out.write(payload.data(), static_cast<std::streamsize>(payload.size()));

    std::string extra;
    if (sizes64 || offset64) {
      std::string fields;
      if (sizes64) {
        Put64(fields, usize);
        Put64(fields, csize);
      }
      if (offset64) Put64(fields, offset);
      Put16(extra, kZip64ExtraId);
      Put16(extra, static_cast<uint16_t>(fields.size()));
      extra += fields;
    }
    Put32(central, kCentralHeaderSignature);
    Put16(central, version);  // made by (MS-DOS, spec version)
    Put16(central, version);  // needed
    Put16(central, 0);
    Put16(central, method);
    Put16(central, kDosTime);
    Put16(central, kDosDate);
    Put32(central, crc);
    Put32(central, sizes64 ? kMax32 : static_cast<uint32_t>(csize));
    Put32(central, sizes64 ? kMax32 : static_cast<uint32_t>(usize));
    Put16(central, static_cast<uint16_t>(name.size()));
    Put16(central, static_cast<uint16_t>(extra.size()));
    Put16(central, 0);            // comment
    Put16(central, 0);            // disk
    Put16(central, 0);            // internal attributes
    Put32(central, 0x81A40000u);  // external attributes: regular file, 0644
    Put32(central, offset64 ? kMax32 : static_cast<uint32_t>(offset));
    central += name;
    central += extra;
    offset += local.size() + payload.size();
  }
  const uint64_t cd_offset = offset;
  const uint64_t cd_size = central.size();
  const uint64_t num_entries = arrays.size();
  const bool end64 = options.force_zip64 || num_entries >= kMax16 ||
                     cd_offset >= kMax32 || cd_size >= kMax32;
  std::string tail = central;
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
  out.write(tail.data(), static_cast<std::streamsize>(tail.size()));
  if (!out) throw IoError(fmt::format("{}: write failed", path.string()));
  writer.Commit();
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
