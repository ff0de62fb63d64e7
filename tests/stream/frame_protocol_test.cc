#include "framework/stream/frame_protocol.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace soma {
namespace {

using ::testing::HasSubstr;

StreamFrame ThreePoints() {
  StreamFrame frame;
  frame.number = 42;
  frame.timestamp = 0.35;
  frame.Add(7, 1.5f, -2.25f, 1000.f, 0.5f);
  frame.Add(-1, 0.f, 0.f, 0.f, -1.f);
  frame.Add(3, 10.f, 20.f, 30.f, 0.f);
  return frame;
}

template <typename Fn>
std::string IoErrorOf(Fn&& fn) {
  return testing::ErrorMessage<IoError>(std::forward<Fn>(fn));
}

TEST(FrameProtocol, RoundTripIsExactAndLittleEndian) {
  const StreamFrame frame = ThreePoints();
  const std::vector<uint8_t> bytes = EncodeFramePacket(frame);
  ASSERT_EQ(bytes.size(), kFramePacketHeaderBytes + 3 * kFramePacketPointBytes);
  EXPECT_EQ(std::string(bytes.begin(), bytes.begin() + 4), "SOMF");
  EXPECT_EQ(bytes[4], 1);  // version 1, little-endian
  EXPECT_EQ(bytes[5], 0);
  EXPECT_EQ(bytes[8], 42);  // frame number, low byte first
  EXPECT_EQ(bytes[24], 3);  // N
  EXPECT_EQ(bytes[28], 7);  // first track id
  const StreamFrame back = DecodeFramePacket(bytes, "test");
  EXPECT_EQ(back.number, 42);
  EXPECT_EQ(back.timestamp, 0.35);
  EXPECT_EQ(back.track_ids, frame.track_ids);
  EXPECT_EQ(back.xyz, frame.xyz);
  EXPECT_EQ(back.residuals, frame.residuals);
  EXPECT_TRUE(back.IsPresent(0));
  EXPECT_FALSE(back.IsPresent(1));  // negative residual
  EXPECT_TRUE(back.IsPresent(2));
}

TEST(FrameProtocol, EmptyFrameIsValid) {
  StreamFrame frame;
  frame.number = -5;
  const StreamFrame back = DecodeFramePacket(EncodeFramePacket(frame), "t");
  EXPECT_EQ(back.number, -5);
  EXPECT_EQ(back.num_points(), 0);
}

TEST(FrameProtocol, BadMagicIsNamed) {
  std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  bytes[0] = 'X';
  EXPECT_THAT(IoErrorOf([&] { DecodeFramePacket(bytes, "client 1"); }),
              HasSubstr("client 1: not a frame packet: bad magic"));
}

TEST(FrameProtocol, OtherVersionIsRefused) {
  std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  bytes[4] = 2;
  EXPECT_THAT(IoErrorOf([&] { DecodeFramePacket(bytes, "c"); }),
              HasSubstr("protocol version 2; this soma speaks version 1"));
}

TEST(FrameProtocol, UnknownFlagsAreRefused) {
  std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  bytes[6] = 1;
  EXPECT_THAT(IoErrorOf([&] { DecodeFramePacket(bytes, "c"); }),
              HasSubstr("flags 0x0001"));
}

TEST(FrameProtocol, GarbagePointCountIsRefusedBeforeAllocating) {
  std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  bytes[24] = 0xff;
  bytes[25] = 0xff;
  bytes[26] = 0xff;
  bytes[27] = 0x7f;
  EXPECT_THAT(IoErrorOf([&] { DecodeFramePacketHeader(bytes, "c"); }),
              HasSubstr("declares 2147483647 points; at most 4096"));
}

TEST(FrameProtocol, EveryTruncationIsAnErrorNotACrash) {
  const std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  for (size_t n = 0; n < bytes.size(); ++n) {
    const std::span<const uint8_t> prefix(bytes.data(), n);
    EXPECT_THAT(IoErrorOf([&] { DecodeFramePacket(prefix, "c"); }),
                HasSubstr("truncated"))
        << n << " bytes";
  }
}

TEST(FrameProtocol, TrailingBytesAreRefused) {
  std::vector<uint8_t> bytes = EncodeFramePacket(ThreePoints());
  bytes.push_back(0);
  EXPECT_THAT(IoErrorOf([&] { DecodeFramePacket(bytes, "c"); }),
              HasSubstr("1 trailing bytes after its 3 points"));
}

TEST(FrameProtocol, NonFiniteCoordinateOnlyOnInvalidPoints) {
  StreamFrame frame = ThreePoints();
  frame.xyz[3] = std::numeric_limits<float>::quiet_NaN();  // point 1: invalid
  EXPECT_NO_THROW(DecodeFramePacket(EncodeFramePacket(frame), "c"));
  frame.xyz[0] = std::numeric_limits<float>::infinity();  // point 0: valid
  EXPECT_THAT(
      IoErrorOf([&] { DecodeFramePacket(EncodeFramePacket(frame), "c"); }),
      HasSubstr("frame 42 point 0: non-finite coordinate"));
}

TEST(FrameProtocol, NanResidualAndBadTrackIdsAreRefused) {
  StreamFrame frame = ThreePoints();
  frame.residuals[2] = std::nanf("");
  EXPECT_THAT(
      IoErrorOf([&] { DecodeFramePacket(EncodeFramePacket(frame), "c"); }),
      HasSubstr("point 2: NaN residual"));
  frame = ThreePoints();
  frame.track_ids[2] = 7;
  EXPECT_THAT(
      IoErrorOf([&] { DecodeFramePacket(EncodeFramePacket(frame), "c"); }),
      HasSubstr("track id 7 used by two points"));
  frame.track_ids[2] = -3;
  EXPECT_THAT(
      IoErrorOf([&] { DecodeFramePacket(EncodeFramePacket(frame), "c"); }),
      HasSubstr("track id -3"));
}

TEST(FrameProtocol, NonFiniteTimestampIsRefused) {
  StreamFrame frame = ThreePoints();
  frame.timestamp = std::numeric_limits<double>::infinity();
  EXPECT_THAT(
      IoErrorOf([&] { DecodeFramePacket(EncodeFramePacket(frame), "c"); }),
      HasSubstr("non-finite timestamp"));
}

TEST(FrameProtocol, HelloAndLabelPacketsRoundTrip) {
  const std::vector<std::string> labels = {"C7", "LFHD", ""};
  EXPECT_EQ(DecodeHelloPacket(EncodeHelloPacket(labels), "c"), labels);
  std::vector<uint8_t> hello = EncodeHelloPacket(labels);
  hello.pop_back();
  EXPECT_THAT(IoErrorOf([&] { DecodeHelloPacket(hello, "c"); }),
              HasSubstr("truncated"));

  LabelPacket packet;
  packet.number = 9;
  packet.flags = kLabelFlagDropped;
  packet.latency_ms = 1.25f;
  packet.label_ids = {0, -1, 40};
  packet.confidences = {0.9f, 0.5f, 1.0f};
  const std::vector<uint8_t> bytes = EncodeLabelPacket(packet);
  ASSERT_EQ(bytes.size(), kLabelPacketHeaderBytes + 3 * kLabelPacketPointBytes);
  EXPECT_EQ(DecodeLabelPacketHeader(bytes, "c"), 3u);
  const LabelPacket back = DecodeLabelPacket(bytes, "c");
  EXPECT_EQ(back.number, 9);
  EXPECT_EQ(back.flags, kLabelFlagDropped);
  EXPECT_EQ(back.latency_ms, 1.25f);
  EXPECT_EQ(back.label_ids, packet.label_ids);
  EXPECT_EQ(back.confidences, packet.confidences);
  std::vector<uint8_t> bad = bytes;
  bad[3] = 'F';  // a frame packet's magic
  EXPECT_THAT(IoErrorOf([&] { DecodeLabelPacket(bad, "c"); }),
              HasSubstr("not a label packet"));
}

}  // namespace
}  // namespace soma
