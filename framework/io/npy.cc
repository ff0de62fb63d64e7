#include "framework/io/npy.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/io/little_endian.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>
#include <utility>

namespace soma {
namespace {

using internal::Le16;
using internal::Le32;
using internal::Put16;
using internal::Put32;

constexpr char kNpyMagic[] = "\x93NUMPY";
constexpr size_t kNpyMagicSize = 6;

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

}  // namespace soma
