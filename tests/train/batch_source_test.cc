// Batch sources are pure functions of (epoch, range); the prefetcher delivers
// exactly what direct reads give, in order, and forwards errors.
#include "framework/train/batch_source.h"

#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <string>
#include <vector>

namespace soma {
namespace {

// Frame f has points (f, f, f) and labels f % 3.
LabeledFrames CountingFrames(int64_t frames, int points) {
  LabeledFrames out;
  out.num_points = points;
  for (int64_t f = 0; f < frames; ++f) {
    for (int p = 0; p < points; ++p) {
      for (int c = 0; c < 3; ++c) out.points.push_back(static_cast<float>(f));
      out.labels.push_back(static_cast<int16_t>(f % 3));
    }
  }
  return out;
}

std::vector<int64_t> FrameIds(const LabeledFrames& frames) {
  std::vector<int64_t> ids;
  for (int64_t f = 0; f < frames.num_frames(); ++f) {
    ids.push_back(static_cast<int64_t>(frames.frame_points(f)[0]));
  }
  return ids;
}

TEST(InMemoryBatchSource, InOrderWithoutShuffle) {
  InMemoryBatchSource source(CountingFrames(10, 2), {"a", "b", "c"}, false, 0);
  EXPECT_EQ(source.frames_per_epoch(), 10);
  EXPECT_EQ(source.num_points(), 2);
  EXPECT_EQ(source.num_labels(), 3);
  LabeledFrames out;
  source.Read(5, 3, 4, &out);
  EXPECT_EQ(FrameIds(out), (std::vector<int64_t>{3, 4, 5, 6}));
  EXPECT_EQ(out.labels[2], 4 % 3);  // frame 4, point 0
  EXPECT_THROW(source.Read(0, 8, 3, &out), ShapeError);
}

TEST(InMemoryBatchSource, ShufflePerEpochIsDeterministic) {
  InMemoryBatchSource source(CountingFrames(50, 1), {"a", "b", "c"}, true, 7);
  LabeledFrames e0, e0_again, e1;
  source.Read(0, 0, 50, &e0);
  source.Read(0, 0, 50, &e0_again);
  source.Read(1, 0, 50, &e1);
  EXPECT_EQ(FrameIds(e0), FrameIds(e0_again));
  EXPECT_NE(FrameIds(e0), FrameIds(e1));
  std::vector<int64_t> sorted = FrameIds(e0);
  std::sort(sorted.begin(), sorted.end());
  std::vector<int64_t> all(50);
  std::iota(all.begin(), all.end(), 0);
  EXPECT_EQ(sorted, all);  // a permutation
  // A sub-range equals the slice of the full read.
  LabeledFrames part;
  source.Read(1, 10, 5, &part);
  const std::vector<int64_t> full = FrameIds(e1);
  EXPECT_EQ(FrameIds(part),
            std::vector<int64_t>(full.begin() + 10, full.begin() + 15));
}

TEST(InMemoryBatchSource, SlotsFollowTheirFramesThroughTheShuffle) {
  LabeledFrames frames = CountingFrames(20, 4);
  frames.num_slots = 2;
  for (int64_t f = 0; f < 20; ++f) {
    frames.slots.push_back(static_cast<int16_t>(f));
    frames.slots.push_back(-1);
  }
  const InMemoryBatchSource source(std::move(frames), {"a", "b", "c"}, true, 5);
  LabeledFrames out;
  source.Read(1, 3, 10, &out);
  ASSERT_EQ(out.num_slots, 2);
  ASSERT_EQ(out.slots.size(), 20u);
  const std::vector<int64_t> ids = FrameIds(out);
  for (int64_t i = 0; i < 10; ++i) {
    EXPECT_EQ(out.frame_slots(i)[0], ids[static_cast<size_t>(i)]);
    EXPECT_EQ(out.frame_slots(i)[1], -1);
  }
}

TEST(Prefetcher, DeliversTheRequestsInOrder) {
  InMemoryBatchSource source(CountingFrames(40, 3), {"a", "b", "c"}, true, 3);
  std::vector<BatchRequest> requests;
  for (int epoch = 0; epoch < 3; ++epoch) {
    for (int64_t b = 0; b < 5; ++b) requests.push_back({epoch, b * 8, 8});
  }
  for (int depth : {0, 1, 3}) {
    Prefetcher prefetcher(source, requests, depth);
    LabeledFrames batch, direct;
    size_t i = 0;
    while (prefetcher.Next(&batch)) {
      ASSERT_LT(i, requests.size());
      source.Read(
          requests[i].epoch, requests[i].begin, requests[i].count, &direct);
      EXPECT_EQ(batch.points, direct.points) << "depth " << depth;
      EXPECT_EQ(batch.labels, direct.labels);
      ++i;
    }
    EXPECT_EQ(i, requests.size());
  }
}

TEST(Prefetcher, StopsEarlyWithoutHanging) {
  InMemoryBatchSource source(CountingFrames(40, 3), {"a", "b", "c"}, false, 0);
  std::vector<BatchRequest> requests(100, BatchRequest{0, 0, 40});
  Prefetcher prefetcher(source, requests, 2);
  LabeledFrames batch;
  EXPECT_TRUE(prefetcher.Next(&batch));
  // Destroyed with requests outstanding: joins cleanly.
}

class FailingSource : public BatchSource {
 public:
  const std::vector<std::string>& labels() const override { return labels_; }
  int num_points() const override { return 1; }
  int64_t frames_per_epoch() const override { return 10; }
  void Read(int, int64_t begin, int64_t, LabeledFrames* out) const override {
    if (begin >= 2) throw IoError("disk on fire");
    out->num_points = 1;
    out->points.assign(3, 1.0f);
    out->labels.assign(1, 0);
  }

 private:
  std::vector<std::string> labels_ = {"a"};
};

TEST(Prefetcher, ForwardsTheSourceError) {
  FailingSource source;
  Prefetcher prefetcher(source, {{0, 0, 1}, {0, 1, 1}, {0, 2, 1}}, 2);
  LabeledFrames batch;
  EXPECT_TRUE(prefetcher.Next(&batch));
  EXPECT_TRUE(prefetcher.Next(&batch));
  EXPECT_THROW(prefetcher.Next(&batch), IoError);
}

TEST(Hdf5BatchSource, ShuffledPerEpochLikeInMemory) {
  const auto path = testing::CreateTestDir() / "frames.h5";
  DatasetInfo info;
  info.labels = {"a", "b", "c"};
  info.num_points = 2;
  {
    DatasetWriter writer(path, info);
    writer.Append(CountingFrames(30, 2));
    writer.Close();
  }
  Hdf5BatchSource shuffled(path, true, 11);
  InMemoryBatchSource reference(
      CountingFrames(30, 2), {"a", "b", "c"}, true, 11);
  EXPECT_EQ(shuffled.labels(), reference.labels());
  EXPECT_EQ(shuffled.num_points(), 2);
  EXPECT_EQ(shuffled.frames_per_epoch(), 30);
  for (int epoch : {0, 1, 0}) {
    LabeledFrames a, b;
    shuffled.Read(epoch, 5, 10, &a);
    reference.Read(epoch, 5, 10, &b);
    EXPECT_EQ(a.points, b.points) << "epoch " << epoch;
    EXPECT_EQ(a.labels, b.labels);
  }
  Hdf5BatchSource ordered(path, false, 0, 20);
  EXPECT_EQ(ordered.frames_per_epoch(), 20);
  LabeledFrames c;
  ordered.Read(3, 18, 2, &c);
  EXPECT_EQ(FrameIds(c), (std::vector<int64_t>{18, 19}));
  EXPECT_THROW(ordered.Read(0, 19, 2, &c), ShapeError);
  EXPECT_EQ(ordered.slot_table(), nullptr);
}

TEST(Hdf5BatchSource, SlottedFramesBringTheirSlotTable) {
  // A dataset `soma synth` wrote with a layout sampler: the source hands
  // the trainer its slot table, and shuffled batches keep each frame's slot
  // rows with its points.
  const auto path = testing::CreateTestDir() / "slotted.h5";
  DatasetInfo info;
  info.labels = {"slot0", "slot1", "slot2"};
  info.num_points = 2;
  info.num_slots = 3;
  info.slot_table.width = 2;
  info.slot_table.rows = {0, 1, 2, 3, 4, 5, 6, 7};
  info.slot_table.names = {"A", "B", "C", "D"};
  info.slot_table.row_layout = {0, 0, 1, 1};
  info.slot_table.layouts = {"pig39", "random"};
  LabeledFrames frames = CountingFrames(30, 2);
  frames.num_slots = 3;
  for (int64_t f = 0; f < 30; ++f) {  // frame f: rows f % 4, -1, (f + 1) % 4
    for (const int64_t row : {f % 4, int64_t{-1}, (f + 1) % 4}) {
      frames.slots.push_back(static_cast<int16_t>(row));
    }
  }
  {
    DatasetWriter writer(path, info);
    writer.Append(frames);
    writer.Close();
  }
  const Hdf5BatchSource source(path, true, 5);
  ASSERT_NE(source.slot_table(), nullptr);
  EXPECT_EQ(source.slot_table()->names, info.slot_table.names);
  EXPECT_EQ(source.slot_table()->layouts, info.slot_table.layouts);
  LabeledFrames batch;
  source.Read(1, 4, 12, &batch);
  ASSERT_EQ(batch.num_slots, 3);
  for (int64_t i = 0; i < batch.num_frames(); ++i) {
    const int64_t f = static_cast<int64_t>(batch.frame_points(i)[0]);
    EXPECT_EQ(batch.frame_slots(i)[0], f % 4);
    EXPECT_EQ(batch.frame_slots(i)[1], -1);
    EXPECT_EQ(batch.frame_slots(i)[2], (f + 1) % 4);
  }
}

}  // namespace
}  // namespace soma
