// `soma stream` end to end, in process, with the bundled HDM05 model on the
// real HDM05 take: over TCP with the reference client (which disconnects
// mid-frame) and as a C3D replay with both backlog policies.
#include "framework/body/marker_layout.h"
#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/node.h"
#include "framework/config/override.h"
#include "framework/core/error.h"
#include "framework/io/c3d.h"
#include "framework/registry/registry.h"
#include "framework/solve/solve_output.h"
#include "framework/stream/frame_source.h"
#include "framework/tasks/task.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <future>
#include <thread>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string Hdm05Take() {
  return (testing::SharedDataDir() / "c3d" / "HDM_mm_01-02_03_120.c3d")
      .string();
}

std::string Hdm05Model() {
  return (testing::SourceDir() / "models" / "hdm05" / "model.pt").string();
}

/// Frame t of the take as the capture system would stream it: its labelled
/// columns (HDM05's `*k` copies left out), ids = columns. `names` gets the
/// canonical label of each point.
StreamFrame TakeFrame(const C3dData& c3d,
                      int t,
                      std::vector<std::string>* names) {
  StreamFrame frame;
  frame.number = t + 1;
  frame.timestamp = t / c3d.frame_rate;
  names->clear();
  for (int k = 0; k < c3d.num_points; ++k) {
    if (!c3d.valid(t, k) || c3d.labels[size_t(k)].front() == '*') continue;
    const Eigen::Vector3f p = c3d.Point(t, k);
    frame.Add(k, p.x(), p.y(), p.z(), c3d.residuals(t, k));
    names->push_back(CanonicalMarkerLabel(c3d.labels[size_t(k)]));
  }
  return frame;
}

int FreePort() { return TcpSocket::Listen("127.0.0.1", 0).LocalPort(); }

std::unique_ptr<Task> BuildTask(ConfigNode node) {
  node.Set("name", "stream");
  BuildContext build;
  return Instantiate<Task>(node, build);
}

TEST(StreamTask, TcpClientDisconnectingMidFrameKeepsEveryFullFrame) {
  const fs::path dir = testing::CreateTestDir();
  const C3dData take = ReadC3d(Hdm05Take());
  const int port = FreePort();
  ConfigNode tcp = ConfigNode::EmptyMap();
  tcp.Set("port", port);
  tcp.Set("accept_timeout_s", 30);
  tcp.Set("idle_timeout_s", 5);
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("source", "tcp");
  node.Set("tcp", tcp);
  node.Set("checkpoint", Hdm05Model());
  node.Set("stem", "live");
  std::unique_ptr<Task> task = BuildTask(node);
  RunContext ctx;
  ctx.output_dir = dir;
  std::future<std::string> server = std::async(std::launch::async, [&] {
    try {
      task->Run(ConfigNode::EmptyMap(), ctx);
    } catch (const IoError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  });

  std::unique_ptr<FrameClient> client;
  for (int attempt = 0; attempt < 300 && client == nullptr; ++attempt) {
    try {
      client = std::make_unique<FrameClient>("127.0.0.1", port, 5);
    } catch (const IoError&) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
  ASSERT_NE(client, nullptr) << "the stream task never listened";
  ASSERT_EQ(client->labels().size(), 41u);
  constexpr int kFrames = 30;
  int correct = 0, total = 0;
  std::vector<std::string> names;
  for (int t = 0; t < kFrames; ++t) {
    const StreamFrame frame = TakeFrame(take, t, &names);
    client->Send(frame);
    const LabelPacket reply = client->Receive();
    ASSERT_EQ(reply.number, frame.number);
    ASSERT_EQ(reply.label_ids.size(), size_t(frame.num_points()));
    EXPECT_EQ(reply.flags, 0);
    EXPECT_GE(reply.latency_ms, 0.0f);
    for (size_t i = 0; i < names.size(); ++i) {
      const int id = reply.label_ids[i];
      ASSERT_GE(id, -1);
      ASSERT_LT(id, 41);
      correct += id >= 0 && client->labels()[size_t(id)] == names[i];
      ++total;
    }
  }
  // An empty frame, and one whose only point is invalid: replies with no
  // labels and a null.
  StreamFrame empty;
  empty.number = kFrames + 1;
  client->Send(empty);
  EXPECT_TRUE(client->Receive().label_ids.empty());
  StreamFrame invalid;
  invalid.number = kFrames + 2;
  invalid.Add(3, 1.f, 2.f, 3.f, -1.f);
  client->Send(invalid);
  EXPECT_EQ(client->Receive().label_ids, (std::vector<int32_t>{-1}));
  // Half of the next frame, then gone.
  StreamFrame half = TakeFrame(take, kFrames, &names);
  half.number = kFrames + 3;
  const std::vector<uint8_t> next = EncodeFramePacket(half);
  client->SendBytes(std::span<const uint8_t>(next.data(), next.size() / 2));
  client->Close();
  EXPECT_THAT(server.get(), HasSubstr("the client disconnected mid-frame"));
  EXPECT_GT(double(correct) / total, 0.9) << correct << " of " << total;

  // Outputs: complete up to the last full frame.
  const C3dData out = ReadC3d(dir / "live_labeled.c3d");
  EXPECT_EQ(out.num_frames, kFrames + 2);
  EXPECT_EQ(out.labels[0], client->labels()[0]);
  EXPECT_EQ(out.units, "mm");
  EXPECT_EQ(ReadC3d(dir / "live_per_frame.c3d").num_frames, kFrames + 2);
  EXPECT_TRUE(fs::exists(dir / "latency.csv"));
}

TEST(StreamTask, FlushingKeepsTheOutputsCompleteWhileStreaming) {
  const fs::path dir = testing::CreateTestDir();
  const C3dData take = ReadC3d(Hdm05Take());
  const int port = FreePort();
  ConfigNode tcp = ConfigNode::EmptyMap();
  tcp.Set("port", port);
  tcp.Set("accept_timeout_s", 30);
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("source", "tcp");
  node.Set("tcp", tcp);
  node.Set("checkpoint", Hdm05Model());
  node.Set("stem", "live");
  node.Set("flush_every_s", 1e-6);  // after every frame
  std::unique_ptr<Task> task = BuildTask(node);
  RunContext ctx;
  ctx.output_dir = dir;
  std::future<void> server = std::async(
      std::launch::async, [&] { task->Run(ConfigNode::EmptyMap(), ctx); });
  std::unique_ptr<FrameClient> client;
  for (int attempt = 0; attempt < 300 && client == nullptr; ++attempt) {
    try {
      client = std::make_unique<FrameClient>("127.0.0.1", port, 5);
    } catch (const IoError&) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
  ASSERT_NE(client, nullptr) << "the stream task never listened";
  std::vector<std::string> names;
  for (int t = 0; t < 5; ++t) {
    client->Send(TakeFrame(take, t, &names));
    client->Receive();
  }
  // The stream is still open: what a kill -9 now would leave. The flush
  // after frame 5 follows its reply; wait for it.
  int frames = 0;
  for (int attempt = 0; attempt < 100 && frames < 5; ++attempt) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (fs::exists(dir / "live_labeled.c3d")) {
      frames = ReadC3d(dir / "live_labeled.c3d").num_frames;
    }
  }
  EXPECT_EQ(frames, 5);
  client->Close();
  server.get();
  EXPECT_EQ(ReadC3d(dir / "live_labeled.c3d").num_frames, 5);
  EXPECT_GE(ctx.metrics().at("flushes"), 5);
}

ConfigNode ReplayNode(bool realtime, double speed, const std::string& backlog) {
  ConfigNode c3d = ConfigNode::EmptyMap();
  c3d.Set("path", Hdm05Take());
  c3d.Set("realtime", realtime);
  c3d.Set("speed", speed);
  c3d.Set("max_frames", 120);
  ConfigNode node = ConfigNode::EmptyMap();
  node.Set("source", "c3d");
  node.Set("c3d", c3d);
  node.Set("checkpoint", Hdm05Model());
  node.Set("backlog", backlog);
  return node;
}

TEST(StreamTask, ReplayLabelsEveryFrameWithCatchUp) {
  RunContext ctx;
  ctx.output_dir = testing::CreateTestDir();
  BuildTask(ReplayNode(false, 1.0, "catch_up"))
      ->Run(ConfigNode::EmptyMap(), ctx);
  EXPECT_EQ(ctx.metrics().at("frames"), 120);
  EXPECT_EQ(ctx.metrics().at("frames_labelled"), 120);
  EXPECT_EQ(ctx.metrics().at("frames_dropped"), 0);
  EXPECT_GT(ctx.metrics().at("latency_p50_ms"), 0);
  EXPECT_GE(ctx.metrics().at("latency_max_ms"),
            ctx.metrics().at("latency_p99_ms"));
  // The labelled C3D carries the input's points, and most in their columns.
  const C3dData in = ReadC3d(Hdm05Take());
  const C3dData out =
      ReadC3d(ctx.output_dir / "HDM_mm_01-02_03_120_labeled.c3d");
  ASSERT_EQ(out.num_frames, 120);
  int right = 0, labelled = 0;
  for (int k = 0; k < in.num_points; ++k) {
    const std::string name = CanonicalMarkerLabel(in.labels[size_t(k)]);
    const auto it = std::find(out.labels.begin(), out.labels.end(), name);
    if (in.labels[size_t(k)].front() == '*' || it == out.labels.end()) continue;
    const int column = int(it - out.labels.begin());
    for (int t = 0; t < 120; ++t) {
      if (!in.valid(t, k)) continue;
      ++labelled;
      right += out.valid(t, column) && out.Point(t, column) == in.Point(t, k);
    }
  }
  EXPECT_GT(double(right) / labelled, 0.95) << right << " of " << labelled;
}

TEST(StreamTask, DropPolicySkipsFramesWhenTheSourceRunsAhead) {
  RunContext ctx;
  ctx.output_dir = testing::CreateTestDir();
  // 120 frames due within 1 ms (1000x the capture rate): a backlog.
  BuildTask(ReplayNode(true, 1000.0, "drop"))->Run(ConfigNode::EmptyMap(), ctx);
  EXPECT_EQ(ctx.metrics().at("frames"), 120);
  EXPECT_GT(ctx.metrics().at("frames_dropped"), 0);
  EXPECT_EQ(
      ctx.metrics().at("frames_labelled") + ctx.metrics().at("frames_dropped"),
      120);
  EXPECT_EQ(
      ReadC3d(ctx.output_dir / "HDM_mm_01-02_03_120_labeled.c3d").num_frames,
      120);
}

TEST(StreamTask, BadSourceOptionsAreOneLineConfigErrors) {
  ConfigNode node = ReplayNode(false, 1.0, "later");
  EXPECT_THAT(testing::ErrorMessage<ConfigError>([&] { BuildTask(node); }),
              HasSubstr("backlog"));
  node = ReplayNode(false, 1.0, "drop");
  node.Set("source", "udp");
  EXPECT_THAT(testing::ErrorMessage<ConfigError>([&] { BuildTask(node); }),
              HasSubstr("one of c3d, tcp"));
}

/// The project's composed config with `overrides` (the `soma` command line).
ConfigNode ComposeConfig(const std::vector<std::string>& overrides) {
  const std::string configs = (testing::SourceDir() / "configs").string();
  ComposeRequest request{.search_path = {configs}};
  for (const std::string& text : overrides) {
    request.overrides.push_back(ParseOverride(text));
  }
  ConfigNode resolved = Resolve(Compose(request).root, DefaultResolvers());
  resolved.Erase("hydra");
  return resolved;
}

TEST(StreamTask, OnlineBodyCalibratesThenSolvesEveryFrame) {
  const ConfigNode cfg = ComposeConfig({"task=stream",
                                        "task.c3d.path=" + Hdm05Take(),
                                        "task.c3d.realtime=false",
                                        "task.c3d.max_frames=60",
                                        "task.checkpoint=" + Hdm05Model(),
                                        "task.solve.enabled=true",
                                        "task.solve.calibration_frames=30",
                                        "task.solve.background=false"});
  RunContext ctx;
  ctx.output_dir = testing::CreateTestDir();
  BuildContext build;
  Instantiate<Task>(cfg.at("task"), build)->Run(cfg, ctx);
  const SolveOutput fit =
      ReadSolveOutput(ctx.output_dir / "HDM_mm_01-02_03_120_stageii.h5");
  ASSERT_EQ(fit.summaries.size(), 60u);
  int usable = 0;
  for (int t = 0; t < 60; ++t) {
    if (t < 30) {
      EXPECT_FALSE(fit.summaries[size_t(t)].usable()) << t;  // calibrating
    } else {
      usable += fit.summaries[size_t(t)].usable();
    }
  }
  EXPECT_GE(usable, 28);
  EXPECT_EQ(ctx.metrics().at("body_frames"), usable);
  EXPECT_GT(ctx.metrics().at("body_mean_rms_mm"), 0.0);
  EXPECT_LT(ctx.metrics().at("body_mean_rms_mm"), 30.0);

  // Stage I in the background: the same fit, and the stream does not wait
  // for it (frames 30.. until it is done get no body); the output is
  // complete even when the stream ends first.
  const ConfigNode background =
      ComposeConfig({"task=stream",
                     "task.c3d.path=" + Hdm05Take(),
                     "task.c3d.realtime=false",
                     "task.c3d.max_frames=60",
                     "task.checkpoint=" + Hdm05Model(),
                     "task.solve.enabled=true",
                     "task.solve.calibration_frames=30"});
  RunContext bg;
  bg.output_dir = ctx.output_dir / "background";
  fs::create_directories(bg.output_dir);
  Instantiate<Task>(background.at("task"), build)->Run(background, bg);
  const SolveOutput bg_fit =
      ReadSolveOutput(bg.output_dir / "HDM_mm_01-02_03_120_stageii.h5");
  ASSERT_EQ(bg_fit.summaries.size(), 60u);
  // Stage I is reproducible only to rounding that the optimizer carries to
  // its tolerance: two foreground runs of `soma stream` differ by ~5e-9 in
  // the betas, the background fit by ~4e-7 of norm 9.2 (2026-12-05, after
  // bear_walk changed the procedural prior; not yet explained), so "the
  // same fit" is checked to 1e-6 relative (function_tolerance 1e-6).
  EXPECT_TRUE(bg_fit.betas.isApprox(fit.betas, 1e-6))
      << (bg_fit.betas - fit.betas).norm() << " of " << fit.betas.norm();
  EXPECT_EQ(bg_fit.stagei_frames, fit.stagei_frames);
  int first = 60;
  for (int t = 0; t < 60 && first == 60; ++t) {
    if (bg_fit.summaries[size_t(t)].usable()) first = t;
  }
  EXPECT_GE(first, 30);
  EXPECT_GE(bg.metrics().at("body_frames"), (60 - first) - 2);

  // The same subject again, stage I from that fit: no calibration.
  const fs::path stagei = ctx.output_dir / "HDM_mm_01-02_03_120_stageii.h5";
  const ConfigNode again =
      ComposeConfig({"task=stream",
                     "task.c3d.path=" + Hdm05Take(),
                     "task.c3d.realtime=false",
                     "task.c3d.max_frames=20",
                     "task.checkpoint=" + Hdm05Model(),
                     "task.solve.enabled=true",
                     "task.solve.stagei=" + stagei.string()});
  RunContext second;
  second.output_dir = ctx.output_dir / "again";
  fs::create_directories(second.output_dir);
  Instantiate<Task>(again.at("task"), build)->Run(again, second);
  EXPECT_GE(second.metrics().at("body_frames"), 19);
  const SolveOutput refit =
      ReadSolveOutput(second.output_dir / "HDM_mm_01-02_03_120_stageii.h5");
  EXPECT_EQ(refit.betas, fit.betas);

  // A fit of another layout is refused, naming the file.
  const ConfigNode other =
      ComposeConfig({"task=stream",
                     "task.c3d.path=" + Hdm05Take(),
                     "task.c3d.realtime=false",
                     "task.checkpoint=" + Hdm05Model(),
                     "task.solve.enabled=true",
                     "task.solve.stagei=" + stagei.string(),
                     "layout.exclude=[RBAC]"});
  RunContext third;
  third.output_dir = second.output_dir;
  EXPECT_THAT(testing::ErrorMessage<IoError>([&] {
                Instantiate<Task>(other.at("task"), build)->Run(other, third);
              }),
              HasSubstr(stagei.string() + ": fitted with another layout"));
}

}  // namespace
}  // namespace soma
