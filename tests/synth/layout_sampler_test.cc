#include "framework/synth/layout_sampler.h"

#include "framework/body/vertex_descriptors.h"
#include "framework/core/error.h"
#include "framework/testing/body_fixture.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

TEST(BuiltinLayoutSampler, DrawsAreAPureFunctionOfSeedAndBlock) {
  const BuiltinLayoutSampler sampler(ProceduralBody(), {});
  const BuiltinLayoutSampler again(ProceduralBody(), {});
  for (int64_t block = 0; block < 20; ++block) {
    EXPECT_EQ(sampler.Draw(7, block), again.Draw(7, block)) << block;
    EXPECT_EQ(sampler.Draw(7, block), sampler.Draw(7, block)) << block;
    EXPECT_EQ(sampler.SlotDescriptors(sampler.Draw(7, block)),
              again.SlotDescriptors(again.Draw(7, block)));
  }
  // Another seed gives another sequence of draws.
  int differ = 0;
  for (int64_t block = 0; block < 20; ++block) {
    differ += sampler.Draw(7, block) == sampler.Draw(8, block) ? 0 : 1;
  }
  EXPECT_GT(differ, 10);
  EXPECT_EQ(sampler.BlockOf(31), 0);
  EXPECT_EQ(sampler.BlockOf(32), 1);
}

TEST(BuiltinLayoutSampler, EveryLayoutIsDrawnAndItsMarkersFillTheSlots) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "pig39", "soma53"};
  options.max_labels = 60;
  const BuiltinLayoutSampler sampler(ProceduralBody(), options);
  std::set<int> drawn;
  std::set<std::vector<int>> orders;
  for (int64_t block = 0; block < 60; ++block) {
    const LayoutDraw draw = sampler.Draw(1, block);
    drawn.insert(draw.layout);
    const MarkerLayout& layout = sampler.layout(draw.layout);
    const int k = layout.num_markers();
    ASSERT_EQ(static_cast<int>(draw.slot_marker.size()), 60);
    // The first K slots hold each marker once; the rest are padded.
    std::vector<int> markers(draw.slot_marker.begin(),
                             draw.slot_marker.begin() + k);
    if (draw.layout == 0) orders.insert(markers);
    std::sort(markers.begin(), markers.end());
    for (int m = 0; m < k; ++m) ASSERT_EQ(markers[m], m);
    for (int s = k; s < 60; ++s) ASSERT_EQ(draw.slot_marker[s], -1);
    const std::vector<uint8_t> mask = sampler.SlotMask(draw);
    EXPECT_EQ(std::count(mask.begin(), mask.end(), 1), k);
    // Slot descriptors are the layout's, in slot order; padded rows zero.
    const Eigen::MatrixXf q = sampler.SlotDescriptors(draw);
    const Eigen::MatrixXf expected =
        LayoutDescriptors(ComputeVertexDescriptors(ProceduralBody()), layout);
    ASSERT_EQ(q.cols(), sampler.descriptor_width());
    for (int s = 0; s < 60; ++s) {
      if (draw.slot_marker[s] < 0) {
        EXPECT_TRUE(q.row(s).isZero()) << s;
      } else {
        EXPECT_EQ(q.row(s), expected.row(draw.slot_marker[s])) << s;
      }
    }
    const std::vector<std::string> labels = sampler.SlotLabels(draw);
    EXPECT_EQ(labels[0], layout.markers[draw.slot_marker[0]].label);
    EXPECT_EQ(labels[59], "");
  }
  EXPECT_EQ(drawn.size(), 3u);
  EXPECT_GT(orders.size(), 1u);  // slot order is shuffled per block
}

TEST(BuiltinLayoutSampler, LayoutLargerThanTheSlotsIsAOneLineError) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "soma53"};
  options.max_labels = 45;
  try {
    BuiltinLayoutSampler sampler(ProceduralBody(), options);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("soma53"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
  options.layouts.clear();
  EXPECT_THROW(BuiltinLayoutSampler(ProceduralBody(), options), ConfigError);
}

TEST(BuiltinLayoutSampler, SlotRowsIndexTheSlotTable) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "pig39"};
  options.max_labels = 48;
  const BuiltinLayoutSampler sampler(ProceduralBody(), options);
  const SlotTable table = sampler.BuildSlotTable();
  ASSERT_EQ(table.num_rows(), 41 + 39);
  EXPECT_EQ(sampler.row_offset(1), 41);
  EXPECT_EQ(sampler.max_layout_markers(), 41);
  EXPECT_EQ(table.layouts, options.layouts);
  for (int64_t block = 0; block < 8; ++block) {
    const LayoutDraw draw = sampler.Draw(2, block);
    const std::vector<int16_t> rows = sampler.SlotRows(draw);
    const Eigen::MatrixXf q = sampler.SlotDescriptors(draw);
    ASSERT_EQ(static_cast<int>(rows.size()), 48);
    for (int s = 0; s < 48; ++s) {
      if (draw.slot_marker[s] < 0) {
        EXPECT_EQ(rows[s], -1);
        continue;
      }
      ASSERT_EQ(table.row_layout[rows[s]], draw.layout);
      EXPECT_EQ(table.names[rows[s]],
                sampler.layout(draw.layout).markers[draw.slot_marker[s]].label);
      for (int c = 0; c < table.width; ++c) {
        ASSERT_EQ(table.rows[static_cast<size_t>(rows[s]) * table.width + c],
                  q(s, c));
      }
    }
  }
}

TEST(BuiltinLayoutSampler, CycledLayoutsTakeTurns) {
  LayoutSamplerOptions options;
  options.cycle_layouts = true;
  const BuiltinLayoutSampler sampler(ProceduralBody(), options);
  for (int64_t block = 0; block < 9; ++block) {
    EXPECT_EQ(sampler.Draw(4, block).layout, block % 3) << block;
  }
}

}  // namespace
}  // namespace soma
