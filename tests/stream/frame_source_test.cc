// The frame sources of `soma stream`: C3D replay, and the TCP source against
// the reference client on localhost (ephemeral ports), including clients
// that misbehave: malformed packets, disconnects mid-frame, silence.
#include "framework/stream/frame_source.h"

#include "framework/config/node.h"
#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/registry/registry.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <future>
#include <thread>
#include <vector>

namespace soma {
namespace {

using ::testing::HasSubstr;

TcpSourceOptions Local(double idle_timeout_s = 5) {
  TcpSourceOptions options;
  options.port = 0;
  options.accept_timeout_s = 5;
  options.idle_timeout_s = idle_timeout_s;
  return options;
}

StreamFrame Frame(int64_t number, int points) {
  StreamFrame frame;
  frame.number = number;
  frame.timestamp = static_cast<double>(number) / 120;
  for (int i = 0; i < points; ++i) {
    frame.Add(i,
              100.f * static_cast<float>(i + 1),
              static_cast<float>(number),
              1000.f,
              0.5f);
  }
  return frame;
}

/// Runs `client` against a fresh TCP source on an ephemeral port and
/// returns the source, opened (the client runs on its own thread).
struct Session {
  TcpFrameSource source;
  std::future<void> client;
  template <typename Fn>
  Session(TcpSourceOptions options, Fn&& fn) : source(std::move(options)) {
    const int port = source.Listen();
    client = std::async(std::launch::async, [port, fn] {
      FrameClient c("127.0.0.1", port, 5);
      fn(c);
    });
    source.Open({"A", "B", "C"});
  }
};

TEST(TcpFrameSource, ReceivesFramesAndRepliesInOrder) {
  Session s(Local(), [](FrameClient& c) {
    EXPECT_EQ(c.labels(), (std::vector<std::string>{"A", "B", "C"}));
    for (int64_t n = 10; n < 13; ++n) {
      c.Send(Frame(n, 4));
      const LabelPacket reply = c.Receive();
      EXPECT_EQ(reply.number, n);
      EXPECT_EQ(reply.label_ids, (std::vector<int32_t>{0, -1, 2, 1}));
    }
    c.Close();
  });
  StreamFrame frame;
  for (int64_t n = 10; n < 13; ++n) {
    ASSERT_TRUE(s.source.Next(&frame));
    EXPECT_EQ(frame.number, n);
    EXPECT_EQ(frame.num_points(), 4);
    EXPECT_EQ(frame.xyz[3], 200.f);
    EXPECT_GT(frame.arrival, 0.0);
    LabelPacket reply;
    reply.number = frame.number;
    reply.label_ids = {0, -1, 2, 1};
    reply.confidences = {1, 1, 1, 1};
    s.source.Reply(reply);
  }
  EXPECT_FALSE(s.source.Next(&frame));  // closed between frames: the end
  s.client.get();
}

TEST(TcpFrameSource, ClientClosingWithoutReadingRepliesEndsTheStream) {
  Session s(Local(), [](FrameClient& c) {
    for (int64_t n = 1; n <= 50; ++n) c.Send(Frame(n, 40));
    c.Close();  // no reply read
  });
  s.client.get();  // the client is gone before any reply
  // Every frame is read before the first reply: data reaching a socket its
  // owner closed makes the client's kernel abort the connection with a
  // reset, dropping whatever of these 41 KB it had not yet sent, so replying
  // earlier makes the frame count a race, not a property of the source.
  std::vector<int64_t> numbers;
  StreamFrame frame;
  for (int i = 0; i < 50; ++i) {
    ASSERT_TRUE(s.source.Next(&frame)) << "frame " << i + 1;
    numbers.push_back(frame.number);
  }
  for (const int64_t number : numbers) {
    LabelPacket reply;
    reply.number = number;
    reply.label_ids.assign(40, 0);
    reply.confidences.assign(40, 1.0f);
    EXPECT_NO_THROW(s.source.Reply(reply));
  }
  EXPECT_FALSE(s.source.Next(&frame));  // closed between frames: the end
  EXPECT_EQ(numbers.front(), 1);
  EXPECT_EQ(numbers.back(), 50);
}

TEST(TcpFrameSource, DisconnectInsideAFrameIsAnErrorAfterTheFullFrames) {
  Session s(Local(), [](FrameClient& c) {
    c.Send(Frame(1, 3));
    const std::vector<uint8_t> second = EncodeFramePacket(Frame(2, 3));
    c.SendBytes(std::span<const uint8_t>(second.data(), 40));  // 28 + 12
    c.Close();
  });
  StreamFrame frame;
  ASSERT_TRUE(s.source.Next(&frame));
  EXPECT_EQ(frame.number, 1);
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { s.source.Next(&frame); }),
              HasSubstr("the client disconnected mid-frame: frame 2 has 12 of "
                        "its 60 point bytes (3 points; 1 complete frames "
                        "kept)"));
  s.client.get();
}

TEST(TcpFrameSource, DisconnectInsideAHeaderIsAnError) {
  Session s(Local(), [](FrameClient& c) {
    const std::vector<uint8_t> first = EncodeFramePacket(Frame(1, 3));
    c.SendBytes(std::span<const uint8_t>(first.data(), 10));
    c.Close();
  });
  StreamFrame frame;
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { s.source.Next(&frame); }),
              HasSubstr("disconnected mid-frame: 10 of the 28 header bytes"));
  s.client.get();
}

TEST(TcpFrameSource, MalformedPacketIsAnError) {
  Session s(Local(), [](FrameClient& c) {
    std::vector<uint8_t> bytes = EncodeFramePacket(Frame(1, 3));
    bytes[1] = 'Q';
    c.SendBytes(bytes);
  });
  StreamFrame frame;
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { s.source.Next(&frame); }),
              HasSubstr("not a frame packet: bad magic 53 51 4d 46"));
  s.client.get();
}

TEST(TcpFrameSource, FrameNumbersMustIncrease) {
  Session s(Local(), [](FrameClient& c) {
    c.Send(Frame(5, 1));
    c.Send(Frame(5, 1));
  });
  StreamFrame frame;
  ASSERT_TRUE(s.source.Next(&frame));
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { s.source.Next(&frame); }),
              HasSubstr("frame number 5 after 5"));
  s.client.get();
}

TEST(TcpFrameSource, SilentClientTimesOutInsteadOfHanging) {
  std::promise<void> done;
  std::shared_future<void> finished = done.get_future().share();
  Session s(Local(/*idle_timeout_s=*/0.2), [finished](FrameClient& c) {
    const std::vector<uint8_t> first = EncodeFramePacket(Frame(1, 3));
    c.SendBytes(std::span<const uint8_t>(first.data(), 30));
    finished.wait();  // connected, silent
  });
  StreamFrame frame;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { s.source.Next(&frame); }),
              HasSubstr("no data for 0.2s"));
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(3));
  done.set_value();
  s.client.get();
}

TEST(TcpFrameSource, NoClientTimesOut) {
  TcpSourceOptions options = Local();
  options.accept_timeout_s = 0.1;
  TcpFrameSource source(options);
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] { source.Open({"A"}); }),
              HasSubstr("no client connected within 0.1s"));
}

TEST(TcpFrameSource, BacklogIsVisible) {
  std::promise<void> sent;
  std::shared_future<void> ready = sent.get_future().share();
  std::promise<void> release;
  std::shared_future<void> released = release.get_future().share();
  Session s(Local(), [&sent, released](FrameClient& c) {
    c.Send(Frame(1, 2));
    c.Send(Frame(2, 2));
    sent.set_value();
    released.wait();
  });
  ready.wait();
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  StreamFrame frame;
  const double taken = SteadySeconds();
  ASSERT_TRUE(s.source.Next(&frame));
  // Arrival is when the frame was received, not when it was taken: the
  // 100 ms it waited count in its latency (50 ms: room for a slow reader
  // thread on a loaded machine).
  EXPECT_LT(frame.arrival, taken - 0.050);
  EXPECT_TRUE(s.source.Ready());  // frame 2 is waiting
  ASSERT_TRUE(s.source.Next(&frame));
  EXPECT_EQ(frame.number, 2);
  EXPECT_FALSE(s.source.Ready());
  release.set_value();
  s.client.get();
}

std::filesystem::path SmallTake(const std::filesystem::path& dir) {
  C3dData c3d;
  c3d.frame_rate = 100;
  c3d.num_frames = 5;
  c3d.num_points = 3;
  c3d.units = "mm";
  c3d.labels = {"a", "b", "c"};
  c3d.num_file_labels = 3;
  c3d.points.setZero(5, 9);
  c3d.residuals.setZero(5, 3);
  for (int t = 0; t < 5; ++t) {
    for (int k = 0; k < 9; ++k)
      c3d.points(t, k) = static_cast<float>(10 * t + k + 1);
  }
  c3d.residuals(2, 1) = -1.0f;  // point b missing in frame 2
  std::filesystem::path path = dir / "take.c3d";
  WriteC3d(path, c3d);
  return path;
}

TEST(C3dReplaySource, ReplaysColumnsAsTrajectories) {
  C3dReplayOptions options;
  options.path = SmallTake(testing::CreateTestDir()).string();
  options.realtime = false;
  C3dReplaySource source(options);
  source.Open({});
  EXPECT_EQ(source.frame_rate(), 100);
  EXPECT_EQ(source.units(), "mm");
  EXPECT_DOUBLE_EQ(source.metres_per_unit(), 0.001);
  StreamFrame frame;
  std::vector<int> points;
  while (source.Next(&frame)) {
    points.push_back(frame.num_points());
    if (frame.number == 3) {  // 1-based: the third frame
      EXPECT_EQ(frame.track_ids, (std::vector<int32_t>{0, 2}));
      EXPECT_EQ(frame.xyz[3], 27.f);  // column c, x = 10 * 2 + 6 + 1
    }
  }
  EXPECT_EQ(points, (std::vector<int>{3, 3, 2, 3, 3}));
  EXPECT_FALSE(source.Next(&frame));  // a C3D that ended stays ended
  EXPECT_FALSE(source.Ready());
}

TEST(C3dReplaySource, ModelOutputsAreNotReplayed) {
  // A Vicon Nexus export: 35 markers beside Plug-in Gait's angles, forces
  // ... and its 78 virtual points. Only the markers stream.
  C3dReplayOptions options;
  options.path =
      (testing::SharedDataDir() / "c3d" / "PiG_Motion-FlatFoot-Hole.c3d")
          .string();
  options.realtime = false;
  options.max_frames = 20;
  C3dReplaySource source(options);
  source.Open({});
  const C3dData c3d = ReadC3d(options.path);
  const std::vector<bool> outputs = ModelOutputColumns(c3d);
  StreamFrame frame;
  int frames = 0;
  while (source.Next(&frame)) {
    const int row = frames++;
    std::vector<int32_t> expected;
    for (int k = 0; k < c3d.num_points; ++k) {
      if (!outputs[k] && c3d.valid(row, k)) expected.push_back(k);
    }
    EXPECT_EQ(frame.track_ids, expected) << "frame " << row;
    EXPECT_LE(frame.num_points(), 35);
  }
  EXPECT_EQ(frames, 20);
}

TEST(C3dReplaySource, RealtimeKeepsTheCaptureRate) {
  C3dReplayOptions options;
  options.path = SmallTake(testing::CreateTestDir()).string();
  options.speed = 2.0;  // 200 Hz: 5 frames span 20 ms
  C3dReplaySource source(options);
  source.Open({});
  EXPECT_EQ(source.frame_rate(), 100);    // written to outputs
  EXPECT_EQ(source.arrival_rate(), 200);  // the latency budget's period
  StreamFrame frame;
  const double start = SteadySeconds();
  std::vector<double> arrivals;
  while (source.Next(&frame)) arrivals.push_back(frame.arrival);
  EXPECT_GE(SteadySeconds() - start, 0.019);
  ASSERT_EQ(arrivals.size(), 5u);
  EXPECT_NEAR(arrivals[4] - arrivals[0], 0.020, 1e-9);  // due times
}

TEST(C3dReplaySource, LateConsumerSeesTheBacklog) {
  C3dReplayOptions options;
  options.path = SmallTake(testing::CreateTestDir()).string();
  C3dReplaySource source(options);
  source.Open({});
  StreamFrame frame;
  ASSERT_TRUE(source.Next(&frame));
  EXPECT_FALSE(source.Ready());  // frame 2 is due in 10 ms
  std::this_thread::sleep_for(std::chrono::milliseconds(25));
  EXPECT_TRUE(source.Ready());
}

TEST(FrameSourceRegistry, BuildsBothSourcesAndRejectsUnknownKeys) {
  BuildContext ctx;
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("name", "tcp");
  node.Set("port", 0);
  EXPECT_NE(Instantiate<FrameSource>(node, ctx), nullptr);
  node.Set("prot", 1);
  EXPECT_THAT(testing::ErrorMessage<ConfigError>(
                  [&] { Instantiate<FrameSource>(node, ctx); }),
              HasSubstr("prot"));
  ConfigNode c3d = ConfigNode::EmptyMap();
  c3d.Set("name", "c3d");
  c3d.Set("path", "x.c3d");
  c3d.Set("speed", 0.0);
  EXPECT_THAT(testing::ErrorMessage<ConfigError>(
                  [&] { Instantiate<FrameSource>(c3d, ctx); }),
              HasSubstr("speed > 0"));
}

}  // namespace
}  // namespace soma
