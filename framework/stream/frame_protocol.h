// The binary frame protocol of `soma stream` (README "File formats", "Live
// frame protocol"). Version 1, every field little-endian:
//
//   frame packet (client -> soma), 28 + 20 N bytes:
//     0  char[4]  magic "SOMF"
//     4  uint16   version (1)
//     6  uint16   flags (0; reserved)
//     8  int64    frame number (strictly increasing)
//    16  float64  timestamp, seconds
//    24  uint32   N, points in this frame (<= kMaxStreamPoints)
//    28  N x {int32 track id (-1: none), float32 x, y, z (millimetres),
//             float32 residual (< 0: invalid point, ignored)}
//
//   hello packet (soma -> client, once, right after accepting):
//     "SOMH", uint16 version, uint16 flags (0), uint32 L, then L labels as
//     {uint16 length, bytes} (the label ids of the label packets)
//
//   label packet (soma -> client, one per frame packet, in order, when
//   replies are on), 28 + 8 N bytes:
//     0  char[4]  magic "SOML"
//     4  uint16   version (1)
//     6  uint16   flags (bit 0: the frame was dropped, not labelled)
//     8  int64    frame number
//    16  float32  latency, milliseconds (frame received -> labels sent)
//    20  uint32   reserved (0)
//    24  uint32   N (the frame's point count; 0 when dropped)
//    28  N x {int32 label id (-1: null), float32 confidence}
//
// A stream ends when the client closes the connection between two frame
// packets; closing inside a packet is an error (the frames before it stand).
#pragma once

#include "framework/stream/frame.h"

#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace soma {

inline constexpr uint16_t kStreamProtocolVersion = 1;
inline constexpr size_t kFramePacketHeaderBytes = 28;
inline constexpr size_t kFramePacketPointBytes = 20;
inline constexpr size_t kLabelPacketHeaderBytes = 28;
inline constexpr size_t kLabelPacketPointBytes = 8;
/// Most points a frame packet may carry (a guard against garbage lengths).
inline constexpr uint32_t kMaxStreamPoints = 4096;
/// Label packet flag: the frame was dropped by the backlog policy.
inline constexpr uint16_t kLabelFlagDropped = 1;

/// A decoded frame packet header.
struct FramePacketHeader {
  int64_t number = 0;
  double timestamp = 0.0;
  uint32_t num_points = 0;
  /// Bytes of the point payload that follows (20 N).
  size_t payload_bytes() const {
    return size_t{num_points} * kFramePacketPointBytes;
  }
};

/// Labels of one frame as sent back to the client.
struct LabelPacket {
  int64_t number = 0;
  uint16_t flags = 0;
  float latency_ms = 0.0f;
  std::vector<int32_t> label_ids;  // per point of the frame, -1 = null
  std::vector<float> confidences;  // per point
};

/// Encodes a frame packet (points in millimetres).
std::vector<uint8_t> EncodeFramePacket(const StreamFrame& frame);

/// Decodes the 28-byte header; IoError (naming `source`) on a bad magic,
/// version, flags or a point count above kMaxStreamPoints.
FramePacketHeader DecodeFramePacketHeader(std::span<const uint8_t> bytes,
                                          const std::string& source);

/// Decodes the point payload of `header` into a frame; IoError on a size
/// mismatch, a non-finite residual, a valid point with a non-finite
/// coordinate, or a track id used twice in the frame.
StreamFrame DecodeFramePayload(const FramePacketHeader& header,
                               std::span<const uint8_t> payload,
                               const std::string& source);

/// Header + payload of one complete packet (exactly its bytes).
StreamFrame DecodeFramePacket(std::span<const uint8_t> bytes,
                              const std::string& source);

std::vector<uint8_t> EncodeHelloPacket(const std::vector<std::string>& labels);
/// Decodes a complete hello packet; IoError if malformed.
std::vector<std::string> DecodeHelloPacket(std::span<const uint8_t> bytes,
                                           const std::string& source);

std::vector<uint8_t> EncodeLabelPacket(const LabelPacket& packet);
/// The point count of a label packet header (28 bytes); IoError if malformed.
uint32_t DecodeLabelPacketHeader(std::span<const uint8_t> header,
                                 const std::string& source);
/// Decodes a complete label packet; IoError if malformed.
LabelPacket DecodeLabelPacket(std::span<const uint8_t> bytes,
                              const std::string& source);

}  // namespace soma
