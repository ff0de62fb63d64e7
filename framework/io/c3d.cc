#include "framework/io/c3d.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/io/line_error.h"
#include "framework/io/marker_labels.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>

namespace soma {
namespace {

static_assert(std::endian::native == std::endian::little,
              "the C3D codec assumes a little-endian host");

constexpr size_t kBlockSize = 512;
constexpr uint8_t kMagic = 0x50;
constexpr int kMaxHeaderEvents = 18;
constexpr int kMaxLabelsPerParameter = 255;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// ---------------------------------------------------------------------------
// Scalar codecs, one per processor type.

inline uint16_t LoadU16Le(const uint8_t* p) {
  return static_cast<uint16_t>(p[0] | (p[1] << 8));
}
inline uint16_t LoadU16Be(const uint8_t* p) {
  return static_cast<uint16_t>((p[0] << 8) | p[1]);
}

// VAX F-float: two little-endian 16-bit words, the first holding sign,
// exponent (bias 128, hidden bit 0.1f) and the high fraction bits. Swapping
// the words gives IEEE's bit layout with an exponent two larger.
inline float DecodeDecFloat(const uint8_t* p) {
  const uint32_t bits =
      static_cast<uint32_t>(p[2]) | (static_cast<uint32_t>(p[3]) << 8) |
      (static_cast<uint32_t>(p[0]) << 16) | (static_cast<uint32_t>(p[1]) << 24);
  const uint32_t exponent = (bits >> 23) & 0xffu;
  if (exponent > 2) return std::bit_cast<float>(bits - (2u << 23));
  const bool negative = (bits >> 31) != 0;
  if (exponent == 0) return negative ? kNaN : 0.0f;  // reserved operand / 0
  const float magnitude =
      std::ldexp(1.0f + static_cast<float>(bits & 0x7fffffu) / 8388608.0f,
                 static_cast<int>(exponent) - 129);
  return negative ? -magnitude : magnitude;
}

struct IntelCodec {
  static int16_t I16(const uint8_t* p) {
    return static_cast<int16_t>(LoadU16Le(p));
  }
  static float F32(const uint8_t* p) {
    float value;
    std::memcpy(&value, p, 4);
    return value;
  }
};

struct DecCodec {
  static int16_t I16(const uint8_t* p) {
    return static_cast<int16_t>(LoadU16Le(p));
  }
  static float F32(const uint8_t* p) { return DecodeDecFloat(p); }
};

struct MipsCodec {
  static int16_t I16(const uint8_t* p) {
    return static_cast<int16_t>(LoadU16Be(p));
  }
  static float F32(const uint8_t* p) {
    uint32_t bits;
    std::memcpy(&bits, p, 4);
    return std::bit_cast<float>(__builtin_bswap32(bits));
  }
};

// Runtime dispatch for the non-hot paths (header, parameters, analogs).
class Codec {
 public:
  explicit Codec(C3dProcessor processor) : processor_(processor) {}
  int16_t I16(const uint8_t* p) const {
    return processor_ == C3dProcessor::kMips ? MipsCodec::I16(p)
                                             : IntelCodec::I16(p);
  }
  uint16_t U16(const uint8_t* p) const { return static_cast<uint16_t>(I16(p)); }
  float F32(const uint8_t* p) const {
    switch (processor_) {
      case C3dProcessor::kDec:
        return DecCodec::F32(p);
      case C3dProcessor::kMips:
        return MipsCodec::F32(p);
      case C3dProcessor::kIntel:
        break;
    }
    return IntelCodec::F32(p);
  }

 private:
  C3dProcessor processor_;
};

// ---------------------------------------------------------------------------
// Helpers.

char AsciiLower(char c) {
  return (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c;
}

bool EqualsIgnoreCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (AsciiLower(a[i]) != AsciiLower(b[i])) return false;
  }
  return true;
}

bool IsBlank(char c) {
  return c == ' ' || c == '\0' || c == '\t' || c == '\r' || c == '\n';
}

std::string Trim(std::string_view s) {
  size_t begin = 0;
  size_t end = s.size();
  while (begin < end && IsBlank(s[begin])) ++begin;
  while (end > begin && IsBlank(s[end - 1])) --end;
  return std::string(s.substr(begin, end - begin));
}

// Product of dims, 0 if any dim is 0, saturating at INT64_MAX.
int64_t DimsProduct(const std::vector<int>& dims, size_t first = 0) {
  for (size_t i = first; i < dims.size(); ++i) {
    if (dims[i] == 0) return 0;
  }
  int64_t product = 1;
  for (size_t i = first; i < dims.size(); ++i) {
    if (dims[i] < 0) return 0;
    if (__builtin_mul_overflow(
            product, static_cast<int64_t>(dims[i]), &product)) {
      return std::numeric_limits<int64_t>::max();
    }
  }
  return product;
}

int ElementSize(C3dParameterType type) {
  return type == C3dParameterType::kChar ? 1 : std::abs(static_cast<int>(type));
}

std::string_view TypeName(C3dParameterType type) {
  switch (type) {
    case C3dParameterType::kChar:
      return "char";
    case C3dParameterType::kByte:
      return "byte";
    case C3dParameterType::kInt16:
      return "int16";
    case C3dParameterType::kFloat:
      return "float";
  }
  return "unknown";
}

// Bounds-checked access to the file bytes; every failure is an IoError that
// names the file and the byte offset.
class ByteView {
 public:
  ByteView(std::span<const uint8_t> bytes, std::string_view source)
      : bytes_(bytes), source_(source) {}

  size_t size() const { return bytes_.size(); }
  const uint8_t* data() const { return bytes_.data(); }
  std::string_view source() const { return source_; }

  [[noreturn]] void Fail(uint64_t offset, std::string_view message) const {
    throw IoError(fmt::format(
        "Invalid C3D file '{}' at byte {}: {}", source_, offset, message));
  }

  void Require(uint64_t offset, uint64_t count, std::string_view what) const {
    if (offset > bytes_.size() || count > bytes_.size() - offset) {
      Fail(offset,
           fmt::format("{} needs bytes [{}, {}) but the file has {} bytes",
                       what,
                       offset,
                       offset + count,
                       bytes_.size()));
    }
  }

  const uint8_t* At(uint64_t offset,
                    uint64_t count,
                    std::string_view what) const {
    Require(offset, count, what);
    return bytes_.data() + offset;
  }

 private:
  std::span<const uint8_t> bytes_;
  std::string_view source_;
};

// ---------------------------------------------------------------------------
// Header.

C3dHeader DecodeHeader(const ByteView& view, const Codec& codec) {
  const uint8_t* h = view.At(0, kBlockSize, "the 512-byte header");
  auto word = [&](size_t one_based) {
    return codec.U16(h + 2 * (one_based - 1));
  };
  C3dHeader header;
  header.parameter_block = h[0];
  header.num_points = word(2);
  header.analog_per_frame = word(3);
  header.first_frame = word(4);
  header.last_frame = word(5);
  header.max_interpolation_gap = word(6);
  header.scale = codec.F32(h + 12);
  header.data_start_block = word(9);
  header.analog_samples_per_frame = word(10);
  header.frame_rate = codec.F32(h + 20);
  header.long_event_labels = word(150) == 12345;
  const int num_events = std::min<int>(word(151), kMaxHeaderEvents);
  for (size_t i = 0; i < static_cast<size_t>(num_events); ++i) {
    C3dEvent event;
    event.time = codec.F32(h + 304 + 4 * i);
    event.display = h[376 + i] != 0;
    event.label = Trim(
        std::string_view(reinterpret_cast<const char*>(h + 396 + 4 * i), 4));
    header.events.push_back(std::move(event));
  }
  return header;
}

// ---------------------------------------------------------------------------
// Parameter section.

struct ParameterSection {
  C3dProcessor processor = C3dProcessor::kIntel;
  std::vector<C3dGroup> groups;
};

C3dProcessor DecodeProcessor(const ByteView& view, size_t section_start) {
  const uint8_t byte =
      *view.At(section_start + 3, 1, "the parameter section preamble");
  switch (byte) {
    case 84:
      return C3dProcessor::kIntel;
    case 85:
      return C3dProcessor::kDec;
    case 86:
      return C3dProcessor::kMips;
    default:
      break;
  }
  view.Fail(section_start + 3,
            fmt::format("unknown processor type {} (expected 84 Intel, 85 "
                        "DEC or 86 MIPS)",
                        byte));
}

// Parses the chain of group/parameter records in [start + 4, end).
std::vector<C3dGroup> ParseParameters(const ByteView& view,
                                      const Codec& codec,
                                      size_t start,
                                      size_t end) {
  std::vector<C3dGroup> groups;
  std::map<int, size_t> group_index;
  auto group_for = [&](int id) -> C3dGroup& {
    auto [it, inserted] = group_index.emplace(id, groups.size());
    if (inserted) {
      groups.emplace_back();
      groups.back().id = id;
    }
    return groups[it->second];
  };
  // A bounded reader for this section: nothing past `end`.
  auto need = [&](size_t offset, size_t count, std::string_view what) {
    if (offset > end || count > end - offset) {
      view.Fail(offset,
                fmt::format("{} needs bytes [{}, {}) past the end of the "
                            "parameter section at byte {}",
                            what,
                            offset,
                            static_cast<uint64_t>(offset) + count,
                            end));
    }
    return view.data() + offset;
  };
  auto read_text = [&](size_t offset, size_t length) {
    // Descriptions are free text: clip a length that overruns the section
    // instead of rejecting the file (seen in files from several vendors).
    const size_t available = offset < end ? end - offset : 0;
    const size_t n = std::min(length, available);
    return Trim(std::string_view(
        reinterpret_cast<const char*>(view.data() + offset), n));
  };

  size_t pos = start + 4;
  while (pos + 2 <= end) {
    const auto name_length = static_cast<int8_t>(view.data()[pos]);
    const auto id = static_cast<int8_t>(view.data()[pos + 1]);
    if (name_length == 0 || id == 0) break;  // end of the chain
    const size_t n = static_cast<size_t>(std::abs(name_length));
    const uint8_t* name_bytes = need(pos + 2, n, "a parameter name");
    std::string name(reinterpret_cast<const char*>(name_bytes), n);
    const size_t offset_pos = pos + 2 + n;
    const uint16_t next_offset =
        codec.U16(need(offset_pos, 2, "a parameter's next-record offset"));
    size_t body = offset_pos + 2;
    if (id < 0) {
      C3dGroup& group = group_for(-id);
      group.name = Trim(name);
      group.locked = name_length < 0;
      const uint8_t description_length =
          *need(body, 1, "a group description length");
      group.description = read_text(body + 1, description_length);
    } else {
      C3dParameter parameter;
      parameter.name = Trim(name);
      parameter.locked = name_length < 0;
      const uint8_t* type_bytes = need(body, 2, "a parameter type");
      const auto type = static_cast<int8_t>(type_bytes[0]);
      if (type != -1 && type != 1 && type != 2 && type != 4) {
        view.Fail(body,
                  fmt::format("parameter '{}' has type {} (expected -1, 1, 2 "
                              "or 4)",
                              ForMessage(parameter.name),
                              type));
      }
      parameter.type = static_cast<C3dParameterType>(type);
      const int num_dims = type_bytes[1];
      const uint8_t* dims = need(body + 2, num_dims, "parameter dimensions");
      parameter.dims.assign(dims, dims + num_dims);
      body += 2 + num_dims;
      // Element count, bounded by the bytes left in the section.
      const size_t element_size = ElementSize(parameter.type);
      const size_t room = body <= end ? end - body : 0;
      uint64_t count = DimsProduct(parameter.dims);
      if (count > room / element_size) {
        view.Fail(body,
                  fmt::format("parameter '{}' declares {} elements of {} "
                              "bytes but only {} bytes remain in the "
                              "parameter section",
                              ForMessage(parameter.name),
                              DimsProduct(parameter.dims),
                              element_size,
                              room));
      }
      const size_t data_bytes = count * element_size;
      const uint8_t* data = view.data() + body;
      parameter.raw.assign(data, data + data_bytes);  // memcpy(null, 0) is UB
      switch (parameter.type) {
        case C3dParameterType::kChar:
        case C3dParameterType::kByte:
          break;
        case C3dParameterType::kInt16:
          for (size_t i = 0; i < count; ++i) {
            const uint16_t value = codec.U16(data + 2 * i);
            std::memcpy(parameter.raw.data() + 2 * i, &value, 2);
          }
          break;
        case C3dParameterType::kFloat:
          for (size_t i = 0; i < count; ++i) {
            const float value = codec.F32(data + 4 * i);
            std::memcpy(parameter.raw.data() + 4 * i, &value, 4);
          }
          break;
      }
      body += data_bytes;
      if (body < end) {
        parameter.description = read_text(body + 1, view.data()[body]);
      }
      group_for(id).parameters.push_back(std::move(parameter));
    }
    if (next_offset == 0) break;  // last record
    // offset_pos + next_offset > pos: the walk always moves forward.
    pos = offset_pos + next_offset;
  }
  return groups;
}

// ---------------------------------------------------------------------------
// Interpretation of the standard parameters.

const C3dParameter* FindIn(const std::vector<C3dGroup>& groups,
                           std::string_view group,
                           std::string_view name) {
  for (const C3dGroup& g : groups) {
    if (!EqualsIgnoreCase(g.name, group)) continue;
    if (const C3dParameter* p = g.Find(name)) return p;
  }
  return nullptr;
}

// The first element of a count-like parameter read as unsigned: int16 as
// uint16 (POINT:USED > 32767), bytes as uint8, floats rounded (POINT:FRAMES
// is a float in files with more than 32767 frames).
std::optional<int64_t> UnsignedScalar(const C3dParameter* p) {
  if (p == nullptr || p->raw.empty()) return std::nullopt;
  switch (p->type) {
    case C3dParameterType::kInt16:
      if (p->raw.size() < 2) return std::nullopt;
      return LoadU16Le(p->raw.data());
    case C3dParameterType::kByte:
      return p->raw[0];
    case C3dParameterType::kFloat: {
      if (p->raw.size() < 4) return std::nullopt;
      float value;
      std::memcpy(&value, p->raw.data(), 4);
      if (!std::isfinite(value) || value < 0.0f || value > 4294967295.0f) {
        return std::nullopt;
      }
      return std::llround(value);
    }
    case C3dParameterType::kChar:
      break;
  }
  return std::nullopt;
}

std::optional<float> FloatScalar(const C3dParameter* p) {
  if (p == nullptr || p->type == C3dParameterType::kChar || p->raw.empty()) {
    return std::nullopt;
  }
  const std::vector<float> values = p->AsFloats();
  if (values.empty()) return std::nullopt;
  return values[0];
}

// TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD: two int16 words, low then
// high, forming an unsigned 32-bit frame number.
std::optional<int64_t> TrialField(const C3dParameter* p) {
  if (p == nullptr || p->type != C3dParameterType::kInt16 ||
      p->raw.size() < 2) {
    return std::nullopt;
  }
  int64_t value = LoadU16Le(p->raw.data());
  if (p->raw.size() >= 4) value += int64_t{LoadU16Le(p->raw.data() + 2)} << 16;
  return value;
}

// LABELS, LABELS2, LABELS3, ... concatenated.
// For `base` = "LABELS": 1 for "LABELS", k for "LABELS<k>" (k >= 2), else 0.
int SuffixIndex(std::string_view name, std::string_view base) {
  if (name.size() < base.size() ||
      !EqualsIgnoreCase(name.substr(0, base.size()), base)) {
    return 0;
  }
  const std::string_view digits = name.substr(base.size());
  if (digits.empty()) return 1;
  if (digits.size() > 6 || digits[0] == '0') return 0;
  int k = 0;
  for (char c : digits) {
    if (c < '0' || c > '9') return 0;
    k = 10 * k + (c - '0');
  }
  return k >= 2 ? k : 0;
}

// LABELS, LABELS2, LABELS3, ... concatenated (char parameters of the groups
// named `group`; the first of duplicates wins), at most `max_count` strings.
// One pass over the group: no quadratic lookups on crafted files.
std::vector<std::string> ConcatenatedStrings(
    const std::vector<C3dGroup>& groups,
    std::string_view group,
    std::string_view base,
    size_t max_count) {
  std::map<int, const C3dParameter*> by_index;
  for (const C3dGroup& g : groups) {
    if (!EqualsIgnoreCase(g.name, group)) continue;
    for (const C3dParameter& p : g.parameters) {
      if (p.type != C3dParameterType::kChar) continue;
      if (const int k = SuffixIndex(p.name, base); k > 0) {
        by_index.emplace(k, &p);
      }
    }
  }
  std::vector<std::string> result;
  for (int k = 1; result.size() < max_count; ++k) {
    const auto it = by_index.find(k);
    if (it == by_index.end()) break;
    for (std::string& s : it->second->AsStrings()) {
      if (result.size() >= max_count) break;
      result.push_back(std::move(s));
    }
  }
  return result;
}

// ---------------------------------------------------------------------------
// Data section.

template <typename CodecT, bool kFloatData>
void DecodePoints(const uint8_t* data,
                  int num_frames,
                  int num_points,
                  size_t frame_bytes,
                  float scale,
                  C3dData& out) {
  const float abs_scale = std::fabs(scale);
  for (int f = 0; f < num_frames; ++f) {
    const uint8_t* in = data + static_cast<size_t>(f) * frame_bytes;
    float* xyz = out.points.row(f).data();
    float* residual = out.residuals.row(f).data();
    bool* valid = out.valid.row(f).data();
    for (size_t p = 0; p < static_cast<size_t>(num_points); ++p) {
      float x, y, z, r;
      bool ok;
      if constexpr (kFloatData) {
        x = CodecT::F32(in);
        y = CodecT::F32(in + 4);
        z = CodecT::F32(in + 8);
        const float w = CodecT::F32(in + 12);
        in += 16;
        ok = w >= 0.0f && std::isfinite(x) && std::isfinite(y) &&
             std::isfinite(z);
        // The residual word holds (camera mask << 8 | residual byte) as a
        // float; clamp before the conversion to keep it defined.
        r = ok ? static_cast<float>(static_cast<int>(std::min(w, 65535.0f)) &
                                    0xff) *
                     abs_scale
               : -1.0f;
      } else {
        x = static_cast<float>(CodecT::I16(in)) * scale;
        y = static_cast<float>(CodecT::I16(in + 2)) * scale;
        z = static_cast<float>(CodecT::I16(in + 4)) * scale;
        const int16_t w = CodecT::I16(in + 6);
        in += 8;
        // A huge POINT:SCALE overflows the product to inf: not a point.
        ok = w >= 0 && std::isfinite(x) && std::isfinite(y) && std::isfinite(z);
        r = ok ? static_cast<float>(w & 0xff) * abs_scale : -1.0f;
      }
      if (ok) {
        xyz[3 * p] = x;
        xyz[3 * p + 1] = y;
        xyz[3 * p + 2] = z;
      } else {
        xyz[3 * p] = xyz[3 * p + 1] = xyz[3 * p + 2] = kNaN;
      }
      residual[p] = r;
      valid[p] = ok;
    }
  }
}

template <typename CodecT>
void DecodePointsFor(bool float_data,
                     const uint8_t* data,
                     int num_frames,
                     int num_points,
                     size_t frame_bytes,
                     float scale,
                     C3dData& out) {
  if (float_data) {
    DecodePoints<CodecT, true>(
        data, num_frames, num_points, frame_bytes, scale, out);
  } else {
    DecodePoints<CodecT, false>(
        data, num_frames, num_points, frame_bytes, scale, out);
  }
}

void DecodeAnalogs(const uint8_t* data,
                   const Codec& codec,
                   bool float_data,
                   int num_frames,
                   size_t frame_bytes,
                   size_t analog_offset,
                   const std::vector<C3dGroup>& groups,
                   C3dAnalog& analog) {
  const int channels = analog.num_channels;
  const int samples = analog.samples_per_frame;
  analog.samples.resize(static_cast<Eigen::Index>(num_frames) * samples,
                        channels);
  if (channels == 0 || samples == 0) return;
  // Per-channel calibration (defaults: offset 0, scale 1).
  std::vector<float> offsets(channels, 0.0f);
  std::vector<float> scales(channels, 1.0f);
  float general_scale =
      FloatScalar(FindIn(groups, "ANALOG", "GEN_SCALE")).value_or(1.0f);
  bool unsigned_data = false;
  if (const C3dParameter* format = FindIn(groups, "ANALOG", "FORMAT");
      format != nullptr && format->type == C3dParameterType::kChar) {
    const auto strings = format->AsStrings();
    unsigned_data =
        !strings.empty() && EqualsIgnoreCase(strings[0], "UNSIGNED");
  }
  if (const C3dParameter* p = FindIn(groups, "ANALOG", "OFFSET");
      p != nullptr && p->type == C3dParameterType::kInt16) {
    for (size_t c = 0;
         c < static_cast<size_t>(channels) && 2 * c + 1 < p->raw.size();
         ++c) {
      const uint16_t bits = LoadU16Le(p->raw.data() + 2 * c);
      offsets[c] = unsigned_data
                       ? static_cast<float>(bits)
                       : static_cast<float>(static_cast<int16_t>(bits));
    }
  } else if (p != nullptr && p->type != C3dParameterType::kChar) {
    const auto values = p->AsFloats();
    for (int c = 0; c < channels && c < static_cast<int>(values.size()); ++c) {
      offsets[c] = values[c];
    }
  }
  if (const C3dParameter* p = FindIn(groups, "ANALOG", "SCALE");
      p != nullptr && p->type != C3dParameterType::kChar) {
    const auto values = p->AsFloats();
    for (int c = 0; c < channels && c < static_cast<int>(values.size()); ++c) {
      scales[c] = values[c];
    }
  }
  const size_t word = float_data ? 4 : 2;
  for (int f = 0; f < num_frames; ++f) {
    const uint8_t* in =
        data + static_cast<size_t>(f) * frame_bytes + analog_offset;
    for (int s = 0; s < samples; ++s) {
      float* row =
          analog.samples.row(static_cast<Eigen::Index>(f) * samples + s).data();
      for (int c = 0; c < channels; ++c, in += word) {
        float raw;
        if (float_data) {
          raw = codec.F32(in);
        } else if (unsigned_data) {
          raw = static_cast<float>(codec.U16(in));
        } else {
          raw = static_cast<float>(codec.I16(in));
        }
        row[c] = (raw - offsets[c]) * scales[c] * general_scale;
      }
    }
  }
}

// ---------------------------------------------------------------------------
// Writer helpers.

class ByteWriter {
 public:
  void U8(uint8_t v) { bytes_.push_back(v); }
  void I8(int8_t v) { bytes_.push_back(static_cast<uint8_t>(v)); }
  void U16(uint16_t v) {
    bytes_.push_back(static_cast<uint8_t>(v & 0xff));
    bytes_.push_back(static_cast<uint8_t>(v >> 8));
  }
  void F32(float v) {
    uint8_t b[4];
    std::memcpy(b, &v, 4);
    bytes_.insert(bytes_.end(), b, b + 4);
  }
  void Bytes(std::string_view s) {
    bytes_.insert(bytes_.end(), s.begin(), s.end());
  }
  void Bytes(const std::vector<uint8_t>& b) {
    bytes_.insert(bytes_.end(), b.begin(), b.end());
  }
  void PadTo(size_t multiple) {
    bytes_.resize((bytes_.size() + multiple - 1) / multiple * multiple, 0);
  }
  void PokeU16(size_t offset, uint16_t v) {
    bytes_[offset] = static_cast<uint8_t>(v & 0xff);
    bytes_[offset + 1] = static_cast<uint8_t>(v >> 8);
  }
  size_t size() const { return bytes_.size(); }
  std::vector<uint8_t>& bytes() { return bytes_; }

 private:
  std::vector<uint8_t> bytes_;
};

std::string UpperAscii(std::string_view s) {
  std::string out(s);
  for (char& c : out) {
    if (c >= 'a' && c <= 'z') c = static_cast<char>(c - 'a' + 'A');
  }
  return out;
}

// Serializes the parameter records of `groups` (Intel order) after the
// 4-byte preamble; the last record's next-offset is 0.
void WriteParameterRecords(const std::vector<C3dGroup>& groups,
                           std::string_view source,
                           ByteWriter& out) {
  auto fail = [&](std::string_view what) {
    throw IoError(fmt::format("Cannot write C3D '{}': {}", source, what));
  };
  std::optional<size_t> last_offset_pos;  // of the last record written
  auto write_name = [&](const std::string& name, bool locked, int8_t id) {
    if (name.empty() || name.size() > 127) {
      fail(
          fmt::format("parameter/group name '{}' must have 1 to 127 "
                      "characters",
                      name));
    }
    const int length = static_cast<int>(name.size());
    out.I8(static_cast<int8_t>(locked ? -length : length));
    out.I8(id);
    out.Bytes(UpperAscii(name));
    last_offset_pos = out.size();
  };
  for (const C3dGroup& group : groups) {
    if (group.id < 1 || group.id > 127) {
      fail(fmt::format(
          "group '{}' has id {} (expected 1..127)", group.name, group.id));
    }
    const std::string description = group.description.substr(0, 255);
    write_name(group.name, group.locked, static_cast<int8_t>(-group.id));
    out.U16(static_cast<uint16_t>(2 + 1 + description.size()));
    out.U8(static_cast<uint8_t>(description.size()));
    out.Bytes(description);
    for (const C3dParameter& p : group.parameters) {
      if (p.dims.size() > 7) {
        fail(fmt::format("parameter {}:{} has {} dimensions (at most 7)",
                         group.name,
                         p.name,
                         p.dims.size()));
      }
      for (int d : p.dims) {
        if (d < 0 || d > 255) {
          fail(
              fmt::format("parameter {}:{} has dimension {} (expected "
                          "0..255)",
                          group.name,
                          p.name,
                          d));
        }
      }
      const size_t data_bytes =
          static_cast<size_t>(DimsProduct(p.dims)) * ElementSize(p.type);
      if (p.raw.size() != data_bytes) {
        fail(
            fmt::format("parameter {}:{} holds {} bytes but its {} dims "
                        "need {}",
                        group.name,
                        p.name,
                        p.raw.size(),
                        TypeName(p.type),
                        data_bytes));
      }
      const std::string description = p.description.substr(0, 255);
      const size_t record =
          2 + 1 + 1 + p.dims.size() + data_bytes + 1 + description.size();
      if (record > 65535) {
        fail(fmt::format("parameter {}:{} is too large ({} bytes)",
                         group.name,
                         p.name,
                         record));
      }
      write_name(p.name, p.locked, static_cast<int8_t>(group.id));
      out.U16(static_cast<uint16_t>(record));
      out.I8(static_cast<int8_t>(p.type));
      out.U8(static_cast<uint8_t>(p.dims.size()));
      for (int d : p.dims) out.U8(static_cast<uint8_t>(d));
      out.Bytes(p.raw);
      out.U8(static_cast<uint8_t>(description.size()));
      out.Bytes(description);
    }
  }
  // The last record points nowhere.
  if (last_offset_pos) out.PokeU16(*last_offset_pos, 0);
}

std::vector<int> SplitU32(int64_t value) {
  return {static_cast<int>(value & 0xffff),
          static_cast<int>((value >> 16) & 0xffff)};
}

}  // namespace

// ---------------------------------------------------------------------------
// Public API.

std::string_view ToString(C3dProcessor processor) {
  switch (processor) {
    case C3dProcessor::kIntel:
      return "intel";
    case C3dProcessor::kDec:
      return "dec";
    case C3dProcessor::kMips:
      return "mips";
  }
  return "unknown";
}

int64_t C3dParameter::NumElements() const { return DimsProduct(dims); }

std::vector<std::string> C3dParameter::AsStrings() const {
  if (type != C3dParameterType::kChar) {
    throw IoError(fmt::format(
        "C3D parameter '{}' is {}, not char", name, TypeName(type)));
  }
  std::vector<std::string> result;
  const std::string_view text(reinterpret_cast<const char*>(raw.data()),
                              raw.size());
  if (dims.empty()) {
    result.push_back(Trim(text));
    return result;
  }
  const size_t length = static_cast<size_t>(std::max(dims[0], 0));
  if (length == 0) return result;  // zero-length strings carry nothing
  const size_t count = text.size() / length;
  result.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    result.push_back(Trim(text.substr(i * length, length)));
  }
  return result;
}

std::vector<float> C3dParameter::AsFloats() const {
  std::vector<float> result;
  switch (type) {
    case C3dParameterType::kChar:
      throw IoError(
          fmt::format("C3D parameter '{}' is char, not numeric", name));
    case C3dParameterType::kByte:
      for (uint8_t b : raw) result.push_back(static_cast<float>(b));
      break;
    case C3dParameterType::kInt16:
      for (size_t i = 0; i + 1 < raw.size(); i += 2) {
        result.push_back(static_cast<float>(
            static_cast<int16_t>(LoadU16Le(raw.data() + i))));
      }
      break;
    case C3dParameterType::kFloat:
      for (size_t i = 0; i + 3 < raw.size(); i += 4) {
        float value;
        std::memcpy(&value, raw.data() + i, 4);
        result.push_back(value);
      }
      break;
  }
  return result;
}

std::vector<int> C3dParameter::AsInts() const {
  std::vector<int> result;
  switch (type) {
    case C3dParameterType::kChar:
      throw IoError(
          fmt::format("C3D parameter '{}' is char, not numeric", name));
    case C3dParameterType::kByte:
      for (uint8_t b : raw) result.push_back(b);
      break;
    case C3dParameterType::kInt16:
      for (size_t i = 0; i + 1 < raw.size(); i += 2) {
        result.push_back(static_cast<int16_t>(LoadU16Le(raw.data() + i)));
      }
      break;
    case C3dParameterType::kFloat:
      for (float value : AsFloats()) {
        if (!std::isfinite(value) || std::fabs(value) > 2147483520.0f) {
          throw IoError(fmt::format(
              "C3D parameter '{}' holds {} which is not an int", name, value));
        }
        result.push_back(static_cast<int>(std::lround(value)));
      }
      break;
  }
  return result;
}

C3dParameter C3dParameter::FromStrings(std::string name,
                                       const std::vector<std::string>& values,
                                       std::string description) {
  size_t length = 0;
  for (const std::string& v : values) length = std::max(length, v.size());
  if (length > 255) {
    throw IoError(
        fmt::format("C3D parameter '{}': string of {} characters (at most 255)",
                    name,
                    length));
  }
  if (values.size() > 255) {
    throw IoError(fmt::format(
        "C3D parameter '{}': {} strings (at most 255 per parameter)",
        name,
        values.size()));
  }
  length = std::max<size_t>(length, 1);
  C3dParameter p;
  p.name = std::move(name);
  p.description = std::move(description);
  p.type = C3dParameterType::kChar;
  p.dims = {static_cast<int>(length), static_cast<int>(values.size())};
  p.raw.assign(length * values.size(), ' ');
  for (size_t i = 0; i < values.size(); ++i) {
    std::memcpy(p.raw.data() + i * length, values[i].data(), values[i].size());
  }
  return p;
}

C3dParameter C3dParameter::FromString(std::string name,
                                      std::string_view value,
                                      std::string description) {
  if (value.size() > 255) {
    throw IoError(
        fmt::format("C3D parameter '{}': string of {} characters (at most 255)",
                    name,
                    value.size()));
  }
  C3dParameter p;
  p.name = std::move(name);
  p.description = std::move(description);
  p.type = C3dParameterType::kChar;
  p.dims = {static_cast<int>(value.size())};
  p.raw.assign(value.begin(), value.end());
  return p;
}

C3dParameter C3dParameter::FromInt16s(std::string name,
                                      const std::vector<int>& values,
                                      std::vector<int> dims,
                                      std::string description) {
  C3dParameter p;
  p.name = std::move(name);
  p.description = std::move(description);
  p.type = C3dParameterType::kInt16;
  if (dims.empty() && values.size() != 1) {
    dims = {static_cast<int>(values.size())};
  }
  p.dims = std::move(dims);
  for (int v : values) {
    if (v < -32768 || v > 65535) {
      throw IoError(fmt::format(
          "C3D parameter '{}': {} does not fit in 16 bits", p.name, v));
    }
    const auto bits = static_cast<uint16_t>(v);
    p.raw.push_back(static_cast<uint8_t>(bits & 0xff));
    p.raw.push_back(static_cast<uint8_t>(bits >> 8));
  }
  return p;
}

C3dParameter C3dParameter::FromFloats(std::string name,
                                      const std::vector<float>& values,
                                      std::vector<int> dims,
                                      std::string description) {
  C3dParameter p;
  p.name = std::move(name);
  p.description = std::move(description);
  p.type = C3dParameterType::kFloat;
  if (dims.empty() && values.size() != 1) {
    dims = {static_cast<int>(values.size())};
  }
  p.dims = std::move(dims);
  p.raw.resize(4 * values.size());
  if (!values.empty()) std::memcpy(p.raw.data(), values.data(), p.raw.size());
  return p;
}

const C3dParameter* C3dGroup::Find(std::string_view parameter_name) const {
  for (const C3dParameter& p : parameters) {
    if (EqualsIgnoreCase(p.name, parameter_name)) return &p;
  }
  return nullptr;
}

const C3dGroup* C3dData::FindGroup(std::string_view name) const {
  for (const C3dGroup& g : groups) {
    if (EqualsIgnoreCase(g.name, name)) return &g;
  }
  return nullptr;
}

const C3dParameter* C3dData::FindParameter(std::string_view group,
                                           std::string_view name) const {
  return FindIn(groups, group, name);
}

double C3dData::MetresPerUnit() const {
  return UnitScaleToMetres(units.empty() ? std::string_view("mm") : units);
}

std::vector<bool> NonPositionColumns(const C3dData& c3d) {
  std::set<std::string> outputs;
  for (const char* name :
       {"ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS"}) {
    const C3dParameter* p = c3d.FindParameter("POINT", name);
    if (p == nullptr || p->type != C3dParameterType::kChar) continue;
    for (const std::string& label : p->AsStrings()) outputs.insert(label);
  }
  std::vector<bool> is_output(static_cast<size_t>(c3d.num_points), false);
  for (size_t k = 0; k < is_output.size() && k < c3d.labels.size(); ++k) {
    is_output[k] = outputs.count(c3d.labels[k]) > 0;
  }
  return is_output;
}

std::vector<bool> ModelOutputColumns(const C3dData& c3d) {
  std::vector<bool> is_output = NonPositionColumns(c3d);
  const std::vector<bool> is_virtual = PlugInGaitVirtualPoints(c3d.labels);
  for (size_t k = 0; k < is_output.size() && k < is_virtual.size(); ++k) {
    if (is_virtual[k]) is_output[k] = true;
  }
  return is_output;
}

C3dData ParseC3d(std::span<const uint8_t> bytes,
                 std::string_view source_name,
                 const C3dReadOptions& options) {
  const ByteView view(bytes, source_name);
  if (bytes.size() < kBlockSize) {
    view.Fail(0,
              fmt::format("the file has {} bytes, less than the 512-byte "
                          "header",
                          bytes.size()));
  }
  if (bytes[1] != kMagic) {
    view.Fail(1,
              fmt::format("byte 1 is 0x{:02x}, expected 0x50 (not a C3D "
                          "file?)",
                          bytes[1]));
  }
  const int parameter_block = bytes[0];
  if (parameter_block == 0) {
    view.Fail(0, "the header names parameter block 0 (blocks are 1-based)");
  }
  const size_t section_start = (parameter_block - 1) * kBlockSize;
  view.Require(section_start, 4, "the parameter section preamble");

  C3dData data;
  data.source = std::string(source_name);
  data.processor = DecodeProcessor(view, section_start);
  const Codec codec(data.processor);
  data.header = DecodeHeader(view, codec);
  const C3dHeader& header = data.header;

  // The parameter chain ends at the data section when that follows it.
  size_t section_end = bytes.size();
  if (header.data_start_block > 0) {
    const size_t data_start = (header.data_start_block - 1) * kBlockSize;
    if (data_start > section_start)
      section_end = std::min(section_end, data_start);
  }
  data.groups = ParseParameters(view, codec, section_start, section_end);
  const auto& groups = data.groups;

  // Storage format and scale.
  float scale = header.scale;
  if (!std::isfinite(scale) || scale == 0.0f) {
    scale = FloatScalar(FindIn(groups, "POINT", "SCALE")).value_or(0.0f);
  }
  if (!std::isfinite(scale) || scale == 0.0f) {
    view.Fail(12,
              fmt::format("the point scale is {} in the header and "
                          "POINT:SCALE (expected non-zero: > 0 int16, < 0 "
                          "float)",
                          header.scale));
  }
  data.point_scale = scale;
  const bool float_data = scale < 0.0f;

  // Frame rate.
  data.frame_rate = header.frame_rate;
  if (!std::isfinite(data.frame_rate) || data.frame_rate <= 0.0) {
    data.frame_rate =
        FloatScalar(FindIn(groups, "POINT", "RATE")).value_or(0.0f);
    if (!std::isfinite(data.frame_rate) || data.frame_rate < 0.0) {
      data.frame_rate = 0.0;
    }
  }

  // Points per frame: the header defines the data layout.
  data.num_points = header.num_points;
  if (const auto used = UnsignedScalar(FindIn(groups, "POINT", "USED"));
      used && *used != data.num_points) {
    SOMA_LOG(WARNING,
             "C3D '{}': POINT:USED is {} but the header says {} points; "
             "using the header",
             source_name,
             *used,
             data.num_points);
  }

  // Frame range: header words 4-5; files with more than 65535 frames
  // saturate word 5 and carry the real range in TRIAL:ACTUAL_*_FIELD (or
  // at least POINT:FRAMES, possibly a float).
  int64_t first_frame = header.first_frame;
  int64_t num_frames = int64_t{header.last_frame} - header.first_frame + 1;
  const bool header_saturated = header.last_frame == 65535;
  const auto trial_start =
      TrialField(FindIn(groups, "TRIAL", "ACTUAL_START_FIELD"));
  const auto trial_end =
      TrialField(FindIn(groups, "TRIAL", "ACTUAL_END_FIELD"));
  const auto point_frames = UnsignedScalar(FindIn(groups, "POINT", "FRAMES"));
  if (header_saturated) {
    if (trial_end) {
      first_frame = trial_start.value_or(first_frame);
      num_frames = *trial_end - first_frame + 1;
    } else if (point_frames) {
      num_frames = *point_frames;
    }
  }
  if (num_frames < 0) {
    view.Fail(8,
              fmt::format("the last frame {} is before the first frame {}",
                          first_frame + num_frames - 1,
                          first_frame));
  }
  if (num_frames > std::numeric_limits<int>::max()) {
    view.Fail(8, fmt::format("{} frames is more than supported", num_frames));
  }
  data.first_frame = first_frame;

  // Analog layout.
  const int analog_words = header.analog_per_frame;
  data.analog.samples_per_frame =
      analog_words > 0 ? std::max(header.analog_samples_per_frame, 1) : 0;
  data.analog.num_channels =
      analog_words > 0 ? analog_words / data.analog.samples_per_frame : 0;
  data.analog.rate = FloatScalar(FindIn(groups, "ANALOG", "RATE"))
                         .value_or(static_cast<float>(
                             data.frame_rate * data.analog.samples_per_frame));
  data.analog.labels =
      ConcatenatedStrings(groups, "ANALOG", "LABELS", data.analog.num_channels);
  data.analog.units =
      ConcatenatedStrings(groups, "ANALOG", "UNITS", data.analog.num_channels);

  // Data start: header word 9, else POINT:DATA_START.
  int64_t data_start_block = header.data_start_block;
  const auto param_data_start =
      UnsignedScalar(FindIn(groups, "POINT", "DATA_START"));
  if (data_start_block == 0) data_start_block = param_data_start.value_or(0);
  if (data_start_block == 0) {
    view.Fail(16,
              "the data start block is 0 in the header and POINT:DATA_START");
  }
  if (param_data_start && *param_data_start != 0 &&
      *param_data_start != data_start_block) {
    SOMA_LOG(WARNING,
             "C3D '{}': POINT:DATA_START is {} but the header says {}; using "
             "the header",
             source_name,
             *param_data_start,
             data_start_block);
  }
  const uint64_t data_start = (data_start_block - 1) * kBlockSize;
  const uint64_t word_size = float_data ? 4 : 2;
  const uint64_t frame_bytes =
      (4 * static_cast<uint64_t>(data.num_points) + analog_words) * word_size;

  // Truncation: every declared frame must be complete.
  const uint64_t available =
      bytes.size() > data_start ? bytes.size() - data_start : 0;
  if (frame_bytes > 0 &&
      static_cast<uint64_t>(num_frames) > available / frame_bytes) {
    const int64_t complete = static_cast<int64_t>(available / frame_bytes);
    const uint64_t begin = data_start + complete * frame_bytes;
    if (!options.allow_truncated) {
      throw IoError(fmt::format(
          "Truncated C3D file '{}': frame {} of {} needs bytes [{}, {}) but "
          "the file has {} bytes",
          source_name,
          complete,
          num_frames,
          begin,
          begin + frame_bytes,
          bytes.size()));
    }
    SOMA_LOG(WARNING,
             "Truncated C3D file '{}': {} bytes hold {} of the {} declared "
             "frames; reading those",
             source_name,
             bytes.size(),
             complete,
             num_frames);
    num_frames = complete;
  }
  data.num_frames = static_cast<int>(num_frames);

  // Labels, descriptions, units.
  const size_t num_points = static_cast<size_t>(data.num_points);
  data.labels = ConcatenatedStrings(groups, "POINT", "LABELS", num_points);
  data.num_file_labels = static_cast<int>(data.labels.size());
  for (size_t i = data.labels.size(); i < num_points; ++i) {
    data.labels.push_back(fmt::format("*{}", i));
  }
  data.descriptions =
      ConcatenatedStrings(groups, "POINT", "DESCRIPTIONS", num_points);
  data.descriptions.resize(num_points);
  if (const C3dParameter* p = FindIn(groups, "POINT", "UNITS");
      p != nullptr && p->type == C3dParameterType::kChar) {
    const auto strings = p->AsStrings();
    if (!strings.empty()) data.units = strings[0];
  }

  // Points.
  data.points.resize(data.num_frames,
                     3 * static_cast<Eigen::Index>(num_points));
  data.residuals.resize(data.num_frames, static_cast<Eigen::Index>(num_points));
  data.valid.resize(data.num_frames, static_cast<Eigen::Index>(num_points));
  const uint8_t* data_bytes =
      bytes.data() + std::min<uint64_t>(data_start, bytes.size());
  if (data.num_frames > 0 && num_points > 0) {
    switch (data.processor) {
      case C3dProcessor::kIntel:
        DecodePointsFor<IntelCodec>(float_data,
                                    data_bytes,
                                    data.num_frames,
                                    data.num_points,
                                    frame_bytes,
                                    scale,
                                    data);
        break;
      case C3dProcessor::kDec:
        DecodePointsFor<DecCodec>(float_data,
                                  data_bytes,
                                  data.num_frames,
                                  data.num_points,
                                  frame_bytes,
                                  scale,
                                  data);
        break;
      case C3dProcessor::kMips:
        DecodePointsFor<MipsCodec>(float_data,
                                   data_bytes,
                                   data.num_frames,
                                   data.num_points,
                                   frame_bytes,
                                   scale,
                                   data);
        break;
    }
  }
  if (options.read_analogs) {
    DecodeAnalogs(data_bytes,
                  codec,
                  float_data,
                  data.num_frames,
                  frame_bytes,
                  4 * num_points * word_size,
                  groups,
                  data.analog);
  }
  return data;
}

C3dData ReadC3d(const std::filesystem::path& path,
                const C3dReadOptions& options) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw IoError(fmt::format("Cannot read C3D file '{}': {}",
                              path.string(),
                              ec ? ec.message() : "not a regular file"));
  }
  std::ifstream in(path, std::ios::binary);
  const uintmax_t size = std::filesystem::file_size(path, ec);
  if (!in || ec) {
    throw IoError(fmt::format("Cannot open C3D file '{}': {}",
                              path.string(),
                              ec ? ec.message() : std::strerror(errno)));
  }
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  if (!in.read(reinterpret_cast<char*>(bytes.data()),
               static_cast<std::streamsize>(size))) {
    throw IoError(fmt::format(
        "Cannot read {} bytes from C3D file '{}'", size, path.string()));
  }
  return ParseC3d(bytes, path.string(), options);
}

namespace {

// EncodeC3d with `source` naming the output in messages.
std::vector<uint8_t> EncodeC3dAs(const C3dData& data, std::string_view source) {
  const Eigen::Index num_frames = data.points.rows();
  if (data.points.cols() % 3 != 0) {
    throw ShapeError(fmt::format(
        "Cannot write C3D '{}': points has {} columns, not a multiple of 3",
        source,
        data.points.cols()));
  }
  const Eigen::Index num_points = data.points.cols() / 3;
  if (num_frames != data.num_frames || num_points != data.num_points) {
    throw ShapeError(fmt::format(
        "Cannot write C3D '{}': points is {} x {} but num_frames = {}, "
        "num_points = {}",
        source,
        num_frames,
        data.points.cols(),
        data.num_frames,
        data.num_points));
  }
  auto check_shape =
      [&](Eigen::Index rows, Eigen::Index cols, std::string_view what) {
        if ((rows != 0 || cols != 0) &&
            (rows != num_frames || cols != num_points)) {
          throw ShapeError(fmt::format(
              "Cannot write C3D '{}': {} is {} x {}, expected {} x {}",
              source,
              what,
              rows,
              cols,
              num_frames,
              num_points));
        }
      };
  check_shape(data.residuals.rows(), data.residuals.cols(), "residuals");
  check_shape(data.valid.rows(), data.valid.cols(), "valid");
  if (!data.labels.empty() &&
      data.labels.size() != static_cast<size_t>(num_points)) {
    throw ShapeError(
        fmt::format("Cannot write C3D '{}': {} labels for {} points",
                    source,
                    data.labels.size(),
                    num_points));
  }
  if (num_points > 65535) {
    throw IoError(
        fmt::format("Cannot write C3D '{}': {} points (at most 65535)",
                    source,
                    num_points));
  }
  if (!std::isfinite(data.frame_rate) || data.frame_rate <= 0.0) {
    throw IoError(fmt::format(
        "Cannot write C3D '{}': frame rate {} Hz", source, data.frame_rate));
  }
  // Zero frames are written as first = 1, last = 0 (a zero-frame range
  // needs first > 0 in the unsigned header words).
  const int64_t first_frame = num_frames == 0
                                  ? std::max<int64_t>(data.first_frame, 1)
                                  : data.first_frame;
  const int64_t last_frame = first_frame + num_frames - 1;
  if (first_frame < 0 || last_frame > 0xffffffffLL) {
    throw IoError(
        fmt::format("Cannot write C3D '{}': frames {}..{} out of range",
                    source,
                    first_frame,
                    last_frame));
  }
  const float abs_scale =
      std::isfinite(data.point_scale) && data.point_scale != 0.0f
          ? std::fabs(data.point_scale)
          : 1.0f;
  const float scale = -abs_scale;
  const float rate = static_cast<float>(data.frame_rate);

  // Parameters.
  std::vector<std::string> labels = data.labels;
  for (Eigen::Index i = static_cast<Eigen::Index>(labels.size());
       i < num_points;
       ++i) {
    labels.push_back(fmt::format("*{}", i));
  }
  std::vector<std::string> descriptions = data.descriptions;
  descriptions.resize(num_points);

  C3dGroup point{1, "POINT", "3-D point parameters", false, {}};
  point.parameters.push_back(C3dParameter::FromInt16s(
      "USED", {static_cast<int>(num_points)}, {}, "Number of points"));
  point.parameters.push_back(
      C3dParameter::FromFloats("SCALE", {scale}, {}, "Negative: float data"));
  point.parameters.push_back(
      C3dParameter::FromFloats("RATE", {rate}, {}, "Frame rate (Hz)"));
  point.parameters.push_back(C3dParameter::FromInt16s(
      "DATA_START", {0}, {}, "First data block"));  // patched below
  if (num_frames <= 65535) {
    point.parameters.push_back(C3dParameter::FromInt16s(
        "FRAMES", {static_cast<int>(num_frames)}, {}, "Number of frames"));
  } else {
    point.parameters.push_back(C3dParameter::FromFloats(
        "FRAMES", {static_cast<float>(num_frames)}, {}, "Number of frames"));
  }
  point.parameters.push_back(C3dParameter::FromString(
      "UNITS", data.units.empty() ? "mm" : data.units, "Length unit"));
  for (Eigen::Index begin = 0, k = 1; begin < num_points || k == 1;
       begin += kMaxLabelsPerParameter, ++k) {
    const Eigen::Index end =
        std::min<Eigen::Index>(begin + kMaxLabelsPerParameter, num_points);
    const std::vector<std::string> chunk_labels(labels.begin() + begin,
                                                labels.begin() + end);
    const std::vector<std::string> chunk_descriptions(
        descriptions.begin() + begin, descriptions.begin() + end);
    const std::string suffix = k == 1 ? "" : fmt::format("{}", k);
    point.parameters.push_back(C3dParameter::FromStrings(
        fmt::format("LABELS{}", suffix), chunk_labels));
    point.parameters.push_back(C3dParameter::FromStrings(
        fmt::format("DESCRIPTIONS{}", suffix), chunk_descriptions));
    if (end >= num_points) break;
  }
  C3dGroup analog{2, "ANALOG", "Analog data parameters", false, {}};
  analog.parameters.push_back(C3dParameter::FromInt16s("USED", {0}));
  analog.parameters.push_back(C3dParameter::FromFloats("RATE", {rate}));
  C3dGroup trial{3, "TRIAL", "Trial parameters", false, {}};
  trial.parameters.push_back(
      C3dParameter::FromInt16s("ACTUAL_START_FIELD", SplitU32(first_frame)));
  trial.parameters.push_back(C3dParameter::FromInt16s(
      "ACTUAL_END_FIELD", SplitU32(std::max<int64_t>(last_frame, 0))));
  std::vector<C3dGroup> groups = {point, analog, trial};

  // The parameter section's size does not depend on the DATA_START value:
  // serialize once to size it, then again with the value filled in.
  auto serialize_section = [&]() {
    ByteWriter section;
    section.U8(1);
    section.U8(kMagic);
    section.U8(0);  // number of parameter blocks, patched
    section.U8(static_cast<uint8_t>(C3dProcessor::kIntel));
    WriteParameterRecords(groups, source, section);
    section.PadTo(kBlockSize);
    return std::move(section.bytes());
  };
  const size_t parameter_blocks = serialize_section().size() / kBlockSize;
  const size_t data_start_block = 2 + parameter_blocks;
  if (data_start_block > 65535) {
    throw IoError(fmt::format(
        "Cannot write C3D '{}': the parameter section needs {} blocks",
        source,
        parameter_blocks));
  }
  for (C3dParameter& p : groups[0].parameters) {
    if (p.name == "DATA_START") {
      p = C3dParameter::FromInt16s("DATA_START",
                                   {static_cast<int>(data_start_block)},
                                   {},
                                   p.description);
    }
  }
  std::vector<uint8_t> section = serialize_section();
  SOMA_CHECK_EQ(section.size(), parameter_blocks * kBlockSize);
  // The block count byte saturates; readers follow the record chain and
  // header word 9.
  section[2] = static_cast<uint8_t>(std::min<size_t>(parameter_blocks, 255));

  ByteWriter out;
  out.bytes().assign(kBlockSize, 0);  // header, filled below
  out.bytes().insert(out.bytes().end(), section.begin(), section.end());

  // Header words (Intel order).
  std::vector<uint8_t>& bytes = out.bytes();
  auto poke_word = [&](int one_based, uint16_t value) {
    const size_t offset = 2 * (static_cast<size_t>(one_based) - 1);
    bytes[offset] = static_cast<uint8_t>(value & 0xff);
    bytes[offset + 1] = static_cast<uint8_t>(value >> 8);
  };
  auto poke_float = [&](size_t offset, float value) {
    std::memcpy(bytes.data() + offset, &value, 4);
  };
  bytes[0] = 2;
  bytes[1] = kMagic;
  poke_word(2, static_cast<uint16_t>(num_points));
  poke_word(3, 0);
  poke_word(4, static_cast<uint16_t>(std::min<int64_t>(first_frame, 65535)));
  poke_word(5,
            static_cast<uint16_t>(std::clamp<int64_t>(last_frame, 0, 65535)));
  poke_word(6,
            static_cast<uint16_t>(
                std::clamp(data.header.max_interpolation_gap, 0, 65535)));
  poke_float(12, scale);
  poke_word(9, static_cast<uint16_t>(data_start_block));
  poke_word(10, 0);
  poke_float(20, rate);
  poke_word(150, 12345);
  const int num_events = std::min<int>(
      static_cast<int>(data.header.events.size()), kMaxHeaderEvents);
  poke_word(151, static_cast<uint16_t>(num_events));
  for (size_t i = 0; i < static_cast<size_t>(num_events); ++i) {
    const C3dEvent& event = data.header.events[i];
    poke_float(304 + 4 * i, event.time);
    bytes[376 + i] = event.display ? 1 : 0;
    // Four label characters, blank padded (not NUL terminated).
    for (size_t k = 0; k < 4; ++k) {
      bytes[396 + 4 * i + k] =
          k < event.label.size() ? static_cast<uint8_t>(event.label[k]) : ' ';
    }
  }

  // Data: X, Y, Z, residual word per point; invalid = (0, 0, 0, -1).
  const size_t data_offset = bytes.size();
  bytes.resize(data_offset + static_cast<size_t>(num_frames) * num_points * 16);
  const bool has_residuals = data.residuals.size() > 0;
  const bool has_valid = data.valid.size() > 0;
  uint8_t* cursor = bytes.data() + data_offset;
  for (Eigen::Index f = 0; f < num_frames && num_points > 0; ++f) {
    for (Eigen::Index p = 0; p < num_points; ++p) {
      float word[4];
      const float x = data.points(f, 3 * p);
      const float y = data.points(f, 3 * p + 1);
      const float z = data.points(f, 3 * p + 2);
      const float residual = has_residuals ? data.residuals(f, p) : 0.0f;
      // A huge |scale| can make a valid residual +inf: still valid.
      const bool valid = (!has_valid || data.valid(f, p)) && residual >= 0.0f &&
                         std::isfinite(x) && std::isfinite(y) &&
                         std::isfinite(z);
      if (valid) {
        word[0] = x;
        word[1] = y;
        word[2] = z;
        word[3] = std::clamp(std::round(residual / abs_scale), 0.0f, 255.0f);
      } else {
        word[0] = word[1] = word[2] = 0.0f;
        word[3] = -1.0f;
      }
      std::memcpy(cursor, word, 16);
      cursor += 16;
    }
  }
  out.PadTo(kBlockSize);
  return std::move(out.bytes());
}

}  // namespace

std::vector<uint8_t> EncodeC3d(const C3dData& data) {
  return EncodeC3dAs(data, data.source);
}

void WriteC3d(const std::filesystem::path& path, const C3dData& data) {
  const std::vector<uint8_t> bytes = EncodeC3dAs(data, path.string());
  WriteFileAtomic(path,
                  std::string_view(reinterpret_cast<const char*>(bytes.data()),
                                   bytes.size()));
}

double UnitScaleToMetres(std::string_view units) {
  const std::string trimmed = Trim(units);
  std::string lower;
  for (char c : trimmed) lower.push_back(AsciiLower(c));
  struct Unit {
    std::string_view name;
    double metres;
  };
  static constexpr Unit kUnits[] = {
      {"mm", 1e-3},
      {"millimeter", 1e-3},
      {"millimeters", 1e-3},
      {"millimetre", 1e-3},
      {"millimetres", 1e-3},
      {"cm", 1e-2},
      {"centimeter", 1e-2},
      {"centimeters", 1e-2},
      {"centimetre", 1e-2},
      {"centimetres", 1e-2},
      {"dm", 1e-1},
      {"m", 1.0},
      {"meter", 1.0},
      {"meters", 1.0},
      {"metre", 1.0},
      {"metres", 1.0},
  };
  for (const Unit& unit : kUnits) {
    if (lower == unit.name) return unit.metres;
  }
  throw IoError(fmt::format(
      "Unknown length unit '{}' (expected mm, cm, dm or m)", trimmed));
}

}  // namespace soma
