#include "framework/stream/frame_protocol.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <unordered_set>

namespace soma {
namespace {

constexpr char kFrameMagic[4] = {'S', 'O', 'M', 'F'};
constexpr char kHelloMagic[4] = {'S', 'O', 'M', 'H'};
constexpr char kLabelMagic[4] = {'S', 'O', 'M', 'L'};

/// Little-endian writer.
class Writer {
 public:
  explicit Writer(size_t reserve) { bytes_.reserve(reserve); }
  void Magic(const char (&m)[4]) { bytes_.insert(bytes_.end(), m, m + 4); }
  void U16(uint16_t v) { Uint(v, 2); }
  void U32(uint32_t v) { Uint(v, 4); }
  void I32(int32_t v) { Uint(static_cast<uint32_t>(v), 4); }
  void I64(int64_t v) { Uint(static_cast<uint64_t>(v), 8); }
  void F32(float v) {
    uint32_t u;
    std::memcpy(&u, &v, 4);
    Uint(u, 4);
  }
  void F64(double v) {
    uint64_t u;
    std::memcpy(&u, &v, 8);
    Uint(u, 8);
  }
  void Bytes(const std::string& s) {
    bytes_.insert(bytes_.end(), s.begin(), s.end());
  }
  std::vector<uint8_t> Take() { return std::move(bytes_); }

 private:
  void Uint(uint64_t v, int n) {
    for (int i = 0; i < n; ++i)
      bytes_.push_back(static_cast<uint8_t>(v >> (8 * i)));
  }
  std::vector<uint8_t> bytes_;
};

/// Little-endian reader over a span; IoError naming `source` and the byte
/// offset when it runs out.
class Reader {
 public:
  Reader(std::span<const uint8_t> bytes, const std::string& source)
      : bytes_(bytes), source_(source) {}
  void Magic(const char (&m)[4], const char* what) {
    Need(4, what);
    if (std::memcmp(bytes_.data() + pos_, m, 4) != 0) {
      throw IoError(fmt::format(
          "{}: not a {} packet: bad magic {:02x} {:02x} {:02x} {:02x} at "
          "byte {} (expected '{}')",
          source_,
          what,
          bytes_[pos_],
          bytes_[pos_ + 1],
          bytes_[pos_ + 2],
          bytes_[pos_ + 3],
          pos_,
          std::string(m, 4)));
    }
    pos_ += 4;
  }
  uint16_t U16(const char* what) {
    return static_cast<uint16_t>(Uint(2, what));
  }
  uint32_t U32(const char* what) {
    return static_cast<uint32_t>(Uint(4, what));
  }
  int32_t I32(const char* what) {
    return static_cast<int32_t>(static_cast<uint32_t>(Uint(4, what)));
  }
  int64_t I64(const char* what) { return static_cast<int64_t>(Uint(8, what)); }
  float F32(const char* what) {
    const uint32_t u = static_cast<uint32_t>(Uint(4, what));
    float v;
    std::memcpy(&v, &u, 4);
    return v;
  }
  double F64(const char* what) {
    const uint64_t u = Uint(8, what);
    double v;
    std::memcpy(&v, &u, 8);
    return v;
  }
  std::string Bytes(size_t n, const char* what) {
    Need(n, what);
    std::string s(reinterpret_cast<const char*>(bytes_.data() + pos_), n);
    pos_ += n;
    return s;
  }
  void Version(const char* what) {
    const uint16_t version = U16(what);
    if (version != kStreamProtocolVersion) {
      throw IoError(fmt::format(
          "{}: {} packet of protocol version {}; this soma speaks version {}",
          source_,
          what,
          version,
          kStreamProtocolVersion));
    }
  }
  void Finish(const char* what) const {
    if (pos_ != bytes_.size()) {
      throw IoError(fmt::format("{}: {} packet has {} bytes, expected {}",
                                source_,
                                what,
                                bytes_.size(),
                                pos_));
    }
  }
  size_t pos() const { return pos_; }

 private:
  void Need(size_t n, const char* what) const {
    if (pos_ + n > bytes_.size()) {
      throw IoError(fmt::format(
          "{}: {} packet truncated: {} bytes, needs at least {} (byte {})",
          source_,
          what,
          bytes_.size(),
          pos_ + n,
          pos_));
    }
  }
  uint64_t Uint(int n, const char* what) {
    Need(static_cast<size_t>(n), what);
    uint64_t v = 0;
    for (int i = 0; i < n; ++i) v |= uint64_t{bytes_[pos_ + i]} << (8 * i);
    pos_ += static_cast<size_t>(n);
    return v;
  }
  std::span<const uint8_t> bytes_;
  const std::string& source_;
  size_t pos_ = 0;
};

}  // namespace

bool StreamFrame::IsPresent(int i) const {
  if (!(residuals[static_cast<size_t>(i)] >= 0.0f)) return false;
  const float* p = &xyz[3 * static_cast<size_t>(i)];
  if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
    return false;
  return !(p[0] == 0.0f && p[1] == 0.0f && p[2] == 0.0f);
}

void StreamFrame::Add(int32_t track_id, float x, float y, float z, float r) {
  track_ids.push_back(track_id);
  xyz.insert(xyz.end(), {x, y, z});
  residuals.push_back(r);
}

double SteadySeconds() {
  return std::chrono::duration<double>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::vector<uint8_t> EncodeFramePacket(const StreamFrame& frame) {
  const size_t n = static_cast<size_t>(frame.num_points());
  SOMA_CHECK(frame.xyz.size() == 3 * n && frame.residuals.size() == n)
      << "StreamFrame arrays disagree on the point count";
  Writer w(kFramePacketHeaderBytes + n * kFramePacketPointBytes);
  w.Magic(kFrameMagic);
  w.U16(kStreamProtocolVersion);
  w.U16(0);
  w.I64(frame.number);
  w.F64(frame.timestamp);
  w.U32(static_cast<uint32_t>(n));
  for (size_t i = 0; i < n; ++i) {
    w.I32(frame.track_ids[i]);
    w.F32(frame.xyz[3 * i]);
    w.F32(frame.xyz[3 * i + 1]);
    w.F32(frame.xyz[3 * i + 2]);
    w.F32(frame.residuals[i]);
  }
  return w.Take();
}

FramePacketHeader DecodeFramePacketHeader(std::span<const uint8_t> bytes,
                                          const std::string& source) {
  Reader r(bytes.first(std::min(bytes.size(), kFramePacketHeaderBytes)),
           source);
  FramePacketHeader header;
  r.Magic(kFrameMagic, "frame");
  r.Version("frame");
  if (const uint16_t flags = r.U16("frame"); flags != 0) {
    throw IoError(fmt::format(
        "{}: frame packet flags {:#06x}: no flag is defined in version {} "
        "(must be 0)",
        source,
        flags,
        kStreamProtocolVersion));
  }
  header.number = r.I64("frame");
  header.timestamp = r.F64("frame");
  header.num_points = r.U32("frame");
  if (!std::isfinite(header.timestamp)) {
    throw IoError(fmt::format(
        "{}: frame {} has a non-finite timestamp", source, header.number));
  }
  if (header.num_points > kMaxStreamPoints) {
    throw IoError(
        fmt::format("{}: frame {} declares {} points; at most {} are accepted",
                    source,
                    header.number,
                    header.num_points,
                    kMaxStreamPoints));
  }
  return header;
}

StreamFrame DecodeFramePayload(const FramePacketHeader& header,
                               std::span<const uint8_t> payload,
                               const std::string& source) {
  if (payload.size() != header.payload_bytes()) {
    throw IoError(fmt::format(
        "{}: frame {} truncated: {} of its {} point bytes ({} points)",
        source,
        header.number,
        payload.size(),
        header.payload_bytes(),
        header.num_points));
  }
  StreamFrame frame;
  frame.number = header.number;
  frame.timestamp = header.timestamp;
  const size_t n = header.num_points;
  frame.track_ids.reserve(n);
  frame.xyz.reserve(3 * n);
  frame.residuals.reserve(n);
  Reader r(payload, source);
  std::unordered_set<int32_t> seen;
  for (size_t i = 0; i < n; ++i) {
    const int32_t id = r.I32("frame");
    const float x = r.F32("frame"), y = r.F32("frame"), z = r.F32("frame");
    const float residual = r.F32("frame");
    if (std::isnan(residual)) {
      throw IoError(fmt::format(
          "{}: frame {} point {}: NaN residual", source, header.number, i));
    }
    if (residual >= 0.0f &&
        !(std::isfinite(x) && std::isfinite(y) && std::isfinite(z))) {
      throw IoError(fmt::format(
          "{}: frame {} point {}: non-finite coordinate on a valid point "
          "(residual {} >= 0; mark invalid points with a negative residual)",
          source,
          header.number,
          i,
          residual));
    }
    if (id < -1) {
      throw IoError(fmt::format(
          "{}: frame {} point {}: track id {} (ids are >= 0, or -1 for none)",
          source,
          header.number,
          i,
          id));
    }
    if (id >= 0 && !seen.insert(id).second) {
      throw IoError(fmt::format("{}: frame {}: track id {} used by two points",
                                source,
                                header.number,
                                id));
    }
    frame.Add(id, x, y, z, residual);
  }
  return frame;
}

StreamFrame DecodeFramePacket(std::span<const uint8_t> bytes,
                              const std::string& source) {
  if (bytes.size() < kFramePacketHeaderBytes) {
    throw IoError(
        fmt::format("{}: frame packet truncated: {} bytes, the header alone "
                    "is {}",
                    source,
                    bytes.size(),
                    kFramePacketHeaderBytes));
  }
  const FramePacketHeader header = DecodeFramePacketHeader(bytes, source);
  const std::span<const uint8_t> payload =
      bytes.subspan(kFramePacketHeaderBytes);
  if (payload.size() > header.payload_bytes()) {
    throw IoError(fmt::format(
        "{}: frame {} packet has {} trailing bytes after its {} points",
        source,
        header.number,
        payload.size() - header.payload_bytes(),
        header.num_points));
  }
  return DecodeFramePayload(header, payload, source);
}

std::vector<uint8_t> EncodeHelloPacket(const std::vector<std::string>& labels) {
  Writer w(64);
  w.Magic(kHelloMagic);
  w.U16(kStreamProtocolVersion);
  w.U16(0);
  w.U32(static_cast<uint32_t>(labels.size()));
  for (const std::string& label : labels) {
    SOMA_CHECK(label.size() <= 0xffff) << "label too long";
    w.U16(static_cast<uint16_t>(label.size()));
    w.Bytes(label);
  }
  return w.Take();
}

std::vector<std::string> DecodeHelloPacket(std::span<const uint8_t> bytes,
                                           const std::string& source) {
  Reader r(bytes, source);
  r.Magic(kHelloMagic, "hello");
  r.Version("hello");
  r.U16("hello");
  const uint32_t n = r.U32("hello");
  if (n > kMaxStreamPoints) {
    throw IoError(fmt::format("{}: hello packet lists {} labels", source, n));
  }
  std::vector<std::string> labels;
  for (uint32_t i = 0; i < n; ++i) {
    const uint16_t length = r.U16("hello");
    labels.push_back(r.Bytes(length, "hello"));
  }
  r.Finish("hello");
  return labels;
}

std::vector<uint8_t> EncodeLabelPacket(const LabelPacket& packet) {
  const size_t n = packet.label_ids.size();
  SOMA_CHECK(packet.confidences.size() == n)
      << "LabelPacket arrays disagree on the point count";
  Writer w(kLabelPacketHeaderBytes + n * kLabelPacketPointBytes);
  w.Magic(kLabelMagic);
  w.U16(kStreamProtocolVersion);
  w.U16(packet.flags);
  w.I64(packet.number);
  w.F32(packet.latency_ms);
  w.U32(0);
  w.U32(static_cast<uint32_t>(n));
  for (size_t i = 0; i < n; ++i) {
    w.I32(packet.label_ids[i]);
    w.F32(packet.confidences[i]);
  }
  return w.Take();
}

uint32_t DecodeLabelPacketHeader(std::span<const uint8_t> header,
                                 const std::string& source) {
  Reader r(header.first(std::min(header.size(), kLabelPacketHeaderBytes)),
           source);
  r.Magic(kLabelMagic, "label");
  r.Version("label");
  r.U16("label");
  r.I64("label");
  r.F32("label");
  r.U32("label");
  const uint32_t n = r.U32("label");
  if (n > kMaxStreamPoints) {
    throw IoError(fmt::format("{}: label packet declares {} points (max {})",
                              source,
                              n,
                              kMaxStreamPoints));
  }
  return n;
}

LabelPacket DecodeLabelPacket(std::span<const uint8_t> bytes,
                              const std::string& source) {
  const uint32_t n = DecodeLabelPacketHeader(bytes, source);
  Reader r(bytes, source);
  LabelPacket packet;
  r.Magic(kLabelMagic, "label");
  r.Version("label");
  packet.flags = r.U16("label");
  packet.number = r.I64("label");
  packet.latency_ms = r.F32("label");
  r.U32("label");
  r.U32("label");
  for (uint32_t i = 0; i < n; ++i) {
    packet.label_ids.push_back(r.I32("label"));
    packet.confidences.push_back(r.F32("label"));
  }
  r.Finish("label");
  return packet;
}

}  // namespace soma
