#include "framework/synth/layout_sampler.h"

#include "framework/body/body_model.h"
#include "framework/body/marker_layout.h"
#include "framework/body/vertex_descriptors.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/testing/body_fixture.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <set>
#include <string>
#include <string_view>
#include <vector>

namespace soma {
namespace {

using ::soma::testing::ProceduralBody;

TEST(LayoutSampler, DrawsAreAPureFunctionOfSeedAndBlock) {
  const LayoutSampler sampler(ProceduralBody(), {});
  const LayoutSampler again(ProceduralBody(), {});
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

TEST(LayoutSampler, EveryLayoutIsDrawnAndItsMarkersFillTheSlots) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "pig39", "soma53"};
  options.max_labels = 60;
  const LayoutSampler sampler(ProceduralBody(), options);
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

TEST(LayoutSampler, LayoutLargerThanTheSlotsIsAOneLineError) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "soma53"};
  options.max_labels = 45;
  try {
    LayoutSampler sampler(ProceduralBody(), options);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("soma53"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
  options.layouts.clear();
  EXPECT_THROW(LayoutSampler(ProceduralBody(), options), ConfigError);
}

TEST(LayoutSampler, SlotRowsIndexTheSlotTable) {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "pig39"};
  options.max_labels = 48;
  const LayoutSampler sampler(ProceduralBody(), options);
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

TEST(LayoutSampler, CycledLayoutsTakeTurns) {
  LayoutSamplerOptions options;
  options.cycle_layouts = true;
  const LayoutSampler sampler(ProceduralBody(), options);
  for (int64_t block = 0; block < 9; ++block) {
    EXPECT_EQ(sampler.Draw(4, block).layout, block % 3) << block;
  }
}

TEST(MakeRandomLayout, PlacesDistinctSpacedMarkersOffTheSoles) {
  const BodyModel& body = ProceduralBody();
  Rng rng(11);
  const MarkerLayout layout = MakeRandomLayout(body, 60, 0.04, "r", &rng);
  ASSERT_EQ(layout.num_markers(), 60);
  EXPECT_EQ(layout.surface_model_type, body.name);
  const Eigen::Matrix3Xd normals =
      VertexNormals(body.template_vertices, body.faces);
  std::set<std::string> labels;
  double lowest = 1e9;
  for (int m = 0; m < 60; ++m) {
    const MarkerLayout::Marker& a = layout.markers[m];
    labels.insert(a.label);
    ASSERT_EQ(a.vertex_ids.size(), 1u);
    EXPECT_EQ(a.type, "body");
    EXPECT_EQ(a.distance_from_skin, kDefaultDistanceFromSkin);
    const Eigen::Vector3d x = body.template_vertices.col(a.vertex_ids[0]);
    lowest = std::min(lowest, x.z());
    // A sole vertex has a normal pointing down; none is drawn.
    EXPECT_GT(normals(2, a.vertex_ids[0]), -0.95) << a.label;
    for (int n = m + 1; n < 60; ++n) {
      const Eigen::Vector3d y =
          body.template_vertices.col(layout.markers[n].vertex_ids[0]);
      ASSERT_GE((x - y).norm(), 0.04) << a.label << " " << n;
    }
  }
  EXPECT_EQ(labels.size(), 60u);
  EXPECT_EQ(*labels.begin(), "r_00");
  // Anywhere on the body: from the feet to the head.
  double highest = -1e9;
  for (const MarkerLayout::Marker& a : layout.markers) {
    highest = std::max(highest, body.template_vertices(2, a.vertex_ids[0]));
  }
  EXPECT_GT(highest - lowest,
            0.6 * (body.template_vertices.row(2).maxCoeff() -
                   body.template_vertices.row(2).minCoeff()));
  // The same generator state gives the same layout; another seed another.
  Rng again(11);
  EXPECT_EQ(MakeRandomLayout(body, 60, 0.04, "r", &again), layout);
  Rng other(12);
  EXPECT_NE(MakeRandomLayout(body, 60, 0.04, "r", &other), layout);
}

TEST(MakeRandomLayout, TooManyMarkersTooFarApartIsAOneLineError) {
  Rng rng(1);
  try {
    MakeRandomLayout(ProceduralBody(), 90, 0.5, "r", &rng);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("random_min_spacing"), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
}

ConfigNode Yaml(std::string_view text) { return ParseYaml(text, "test"); }

LayoutSamplerOptions MixedOptions() {
  LayoutSamplerOptions options;
  options.layouts = {"cmu41", "pig39"};
  options.max_labels = 64;
  options.random_layouts = 12;
  options.random_min_markers = 20;
  options.random_max_markers = 50;
  options.random_share = 0.5;
  return options;
}

TEST(LayoutSampler, MixedDrawsListedAndRandomLayoutsInTheirShare) {
  const LayoutSampler sampler(ProceduralBody(), MixedOptions());
  ASSERT_EQ(sampler.num_listed(), 2);
  ASSERT_EQ(sampler.num_layouts(), 2 + 12);
  std::set<int> sizes;
  for (int k = 2; k < 14; ++k) {
    EXPECT_EQ(sampler.group(k), 2);
    const int n = sampler.layout(k).num_markers();
    EXPECT_GE(n, 20);
    EXPECT_LE(n, 50);
    sizes.insert(n);
  }
  EXPECT_GT(sizes.size(), 3u);  // the pool's sizes vary
  // Draws: about half the blocks take the pool (binomial, 2000 blocks: the
  // share is within 0.5 +- 0.06 with probability > 1 - 1e-7), every pool
  // member and both listed layouts come up.
  std::set<int> drawn;
  int pooled = 0;
  const int blocks = 2000;
  for (int64_t block = 0; block < blocks; ++block) {
    const LayoutDraw draw = sampler.Draw(3, block);
    drawn.insert(draw.layout);
    pooled += draw.layout >= 2 ? 1 : 0;
    const int k = sampler.layout(draw.layout).num_markers();
    const std::vector<uint8_t> mask = sampler.SlotMask(draw);
    ASSERT_EQ(std::count(mask.begin(), mask.end(), 1), k);
  }
  EXPECT_EQ(drawn.size(), 14u);
  EXPECT_NEAR(static_cast<double>(pooled) / blocks, 0.5, 0.06);
  // The slot table groups the pool as one layout "random".
  const SlotTable table = sampler.BuildSlotTable();
  EXPECT_EQ(table.layouts,
            (std::vector<std::string>{"cmu41", "pig39", "random"}));
  const LayoutDraw draw = sampler.Draw(3, 0);
  for (const int16_t row : sampler.SlotRows(draw)) {
    if (row >= 0) {
      ASSERT_EQ(table.row_layout[row], sampler.group(draw.layout));
    }
  }
}

TEST(LayoutSampler, ThePoolIsAFunctionOfItsSeed) {
  const LayoutSampler a(ProceduralBody(), MixedOptions());
  const LayoutSampler b(ProceduralBody(), MixedOptions());
  LayoutSamplerOptions reseeded = MixedOptions();
  reseeded.random_seed = 5;
  const LayoutSampler c(ProceduralBody(), reseeded);
  int differ = 0;
  for (int k = 2; k < 14; ++k) {
    EXPECT_EQ(a.layout(k), b.layout(k));
    differ += a.layout(k) == c.layout(k) ? 0 : 1;
  }
  EXPECT_EQ(differ, 12);
  // Without a pool the random options change nothing.
  LayoutSamplerOptions listed = MixedOptions();
  listed.random_layouts = 0;
  LayoutSamplerOptions listed_other = listed;
  listed_other.random_seed = 9;
  listed_other.random_share = 0.9;
  const LayoutSampler d(ProceduralBody(), listed);
  const LayoutSampler e(ProceduralBody(), listed_other);
  for (int64_t block = 0; block < 20; ++block) {
    EXPECT_EQ(d.Draw(1, block), e.Draw(1, block));
  }
}

TEST(LayoutSampler, CycledGroupsGiveThePoolItsTurn) {
  LayoutSamplerOptions options = MixedOptions();
  options.cycle_layouts = true;
  const LayoutSampler sampler(ProceduralBody(), options);
  for (int64_t block = 0; block < 12; ++block) {
    EXPECT_EQ(sampler.group(sampler.Draw(4, block).layout), block % 3) << block;
  }
  // Random layouts only.
  options.layouts.clear();
  options.cycle_layouts = false;
  const LayoutSampler pool(ProceduralBody(), options);
  for (int64_t block = 0; block < 12; ++block) {
    EXPECT_EQ(pool.group(pool.Draw(4, block).layout), 0);
  }
}

TEST(MakePerturbedLayout, KeepsMovesAndRenamesTheListedMarkers) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout soma53 = MakeBuiltinLayout(body, "soma53");
  const std::vector<std::vector<int>> neighbours = VertexNeighbours(
      static_cast<int>(body.template_vertices.cols()), body.faces);
  const auto find = [&](const std::string& label) {
    for (const MarkerLayout::Marker& marker : soma53.markers) {
      if (label == "p_" + marker.label) return &marker;
    }
    return static_cast<const MarkerLayout::Marker*>(nullptr);
  };
  // keep 1, 0 rings: the same markers on the same vertices, renamed.
  Rng same(1);
  const MarkerLayout copy =
      MakePerturbedLayout(soma53, neighbours, 1.0, 0, "p", &same);
  ASSERT_EQ(copy.num_markers(), soma53.num_markers());
  for (const MarkerLayout::Marker& marker : copy.markers) {
    const MarkerLayout::Marker* source = find(marker.label);
    ASSERT_NE(source, nullptr) << marker.label;
    EXPECT_EQ(marker.vertex_ids.front(), source->vertex_ids.front());
    EXPECT_EQ(marker.type, source->type);
    EXPECT_EQ(marker.distance_from_skin, source->distance_from_skin);
  }
  // 2 rings: every marker on its source's 2-ring or vertex, no two on one
  // vertex, most of them moved; keep 0.5 drops about half.
  int moved = 0;
  int kept = 0;
  for (uint64_t seed = 0; seed < 20; ++seed) {
    Rng rng(seed);
    const MarkerLayout perturbed =
        MakePerturbedLayout(soma53, neighbours, 0.5, 2, "p", &rng);
    kept += perturbed.num_markers();
    std::set<int> vertices;
    for (const MarkerLayout::Marker& marker : perturbed.markers) {
      const MarkerLayout::Marker* source = find(marker.label);
      ASSERT_NE(source, nullptr) << marker.label;
      ASSERT_EQ(marker.vertex_ids.size(), 1u);
      const int from = source->vertex_ids.front();
      const int to = marker.vertex_ids.front();
      std::vector<int> ring = NRing(neighbours, from, 2);
      ring.push_back(from);
      EXPECT_NE(std::find(ring.begin(), ring.end(), to), ring.end())
          << marker.label;
      EXPECT_TRUE(vertices.insert(to).second) << marker.label;
      EXPECT_EQ(marker.type, source->type);
      moved += to != from ? 1 : 0;
    }
  }
  const double share = kept / (20.0 * soma53.num_markers());
  EXPECT_NEAR(share, 0.5, 0.1);
  EXPECT_GT(moved, kept * 3 / 4);
  // A copy always keeps one marker.
  Rng few(3);
  EXPECT_EQ(
      MakePerturbedLayout(soma53, neighbours, 1e-9, 1, "p", &few).num_markers(),
      1);
}

TEST(MakePerturbedLayout, TheRingDrawMovesAsManyMarkersNearAsFar) {
  const BodyModel& body = ProceduralBody();
  const MarkerLayout soma53 = MakeBuiltinLayout(body, "soma53");
  const std::vector<std::vector<int>> neighbours = VertexNeighbours(
      static_cast<int>(body.template_vertices.cols()), body.faces);
  std::map<std::string, int> source;
  for (const MarkerLayout::Marker& marker : soma53.markers) {
    source["p_" + marker.label] = marker.vertex_ids.front();
  }
  constexpr int kRings = 4;
  // The share of moved markers at each edge distance 0..kRings.
  const auto distances = [&](PerturbDraw draw) {
    std::vector<double> share(kRings + 1, 0.0);
    int total = 0;
    for (uint64_t seed = 0; seed < 30; ++seed) {
      Rng rng(seed);
      const MarkerLayout copy =
          MakePerturbedLayout(soma53, neighbours, 1.0, kRings, "p", &rng, draw);
      for (const MarkerLayout::Marker& marker : copy.markers) {
        const int from = source.at(marker.label);
        const int to = marker.vertex_ids.front();
        int r = 0;  // the least r whose r-ring holds `to`
        while (to != from && r <= kRings &&
               !std::ranges::binary_search(NRing(neighbours, from, r), to)) {
          ++r;
        }
        if (r > kRings) {
          ADD_FAILURE() << marker.label << " left its ring";
          continue;
        }
        share[r] += 1.0;
        ++total;
      }
    }
    for (double& s : share) s /= total;
    return share;
  };
  const std::vector<double> ring = distances(PerturbDraw::kRing);
  for (int r = 0; r <= kRings; ++r) {
    EXPECT_NEAR(ring[r], 1.0 / (kRings + 1), 0.06) << "distance " << r;
  }
  // The vertex draw (the default) puts most markers on the outer rings.
  const std::vector<double> vertex = distances(PerturbDraw::kVertex);
  EXPECT_GT(vertex[kRings], 0.35);
  EXPECT_LT(vertex[0], 0.05);
}

TEST(LayoutSampler, PerturbedCopiesOfTheListedLayoutsJoinThePool) {
  LayoutSamplerOptions options;
  options.layouts = {"soma53"};
  options.max_labels = 64;
  options.perturbed_layouts = 10;
  options.random_share = 0.5;
  const LayoutSampler sampler(ProceduralBody(), options);
  ASSERT_EQ(sampler.num_layouts(), 1 + 10);
  const int listed = sampler.layout(0).num_markers();
  std::set<int> sizes;
  for (int k = 1; k < 11; ++k) {
    EXPECT_EQ(sampler.group(k), 1);
    EXPECT_LE(sampler.layout(k).num_markers(), listed);
    EXPECT_EQ(sampler.layout(k).markers.front().label.rfind("perturbed", 0),
              0u);
    sizes.insert(sampler.layout(k).num_markers());
  }
  EXPECT_GT(sizes.size(), 2u);
  EXPECT_EQ(sampler.BuildSlotTable().layouts,
            (std::vector<std::string>{"soma53", "perturbed"}));
  // A function of the pool's seed; with random layouts too the pool is
  // "pool", the random layouts first.
  const LayoutSampler again(ProceduralBody(), options);
  options.random_seed = 4;
  const LayoutSampler reseeded(ProceduralBody(), options);
  int differ = 0;
  for (int k = 1; k < 11; ++k) {
    EXPECT_EQ(sampler.layout(k), again.layout(k));
    differ += sampler.layout(k) == reseeded.layout(k) ? 0 : 1;
  }
  EXPECT_GT(differ, 5);
  options.random_layouts = 3;
  options.random_min_markers = 20;
  options.random_max_markers = 40;
  const LayoutSampler both(ProceduralBody(), options);
  ASSERT_EQ(both.num_layouts(), 1 + 3 + 10);
  EXPECT_EQ(both.layout(1).markers.front().label.rfind("random", 0), 0u);
  EXPECT_EQ(both.layout(4).markers.front().label.rfind("perturbed", 0), 0u);
  EXPECT_EQ(both.BuildSlotTable().layouts,
            (std::vector<std::string>{"soma53", "pool"}));
}

TEST(LayoutSamplerOptions, DecodesThePerturbedLayoutsAndRejectsBadValues) {
  const LayoutSamplerOptions options = DecodeLayoutSamplerOptions(
      Yaml("{name: mixed, layouts: [soma53], perturbed_layouts: 5, "
           "perturb_keep: 0.7, perturb_rings: 3}"));
  EXPECT_EQ(options.random_layouts, 0);
  EXPECT_EQ(options.perturbed_layouts, 5);
  EXPECT_EQ(options.perturb_keep, 0.7);
  EXPECT_EQ(options.perturb_rings, 3);
  EXPECT_EQ(options.perturb_draw, PerturbDraw::kVertex);
  EXPECT_EQ(DecodeLayoutSamplerOptions(
                Yaml("{name: mixed, layouts: [soma53], perturbed_layouts: 5, "
                     "perturb_rings: 8, perturb_draw: ring}"))
                .perturb_draw,
            PerturbDraw::kRing);
  for (const char* bad : {
           "{name: mixed, perturbed_layouts: 3, perturb_draw: far}",
           "{name: builtin, perturbed_layouts: 3}",
           "{name: random, layouts: [], perturbed_layouts: 3}",
           "{name: mixed, perturbed_layouts: -1}",
           "{name: mixed, perturbed_layouts: 3, perturb_keep: 0}",
           "{name: mixed, perturbed_layouts: 3, perturb_keep: 1.5}",
           "{name: mixed, perturbed_layouts: 3, perturb_rings: -1}",
           "{name: mixed, perturbed_layouts: 3, perturb_rings: 9}",
       }) {
    try {
      DecodeLayoutSamplerOptions(Yaml(bad));
      ADD_FAILURE() << "no error for " << bad;
    } catch (const ConfigError& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << bad;
    }
  }
}

TEST(LayoutSamplerOptions, DecodesTheRandomPoolAndRejectsBadValues) {
  const LayoutSamplerOptions options = DecodeLayoutSamplerOptions(
      Yaml("{name: mixed, layouts: [cmu41], max_labels: 80, random_layouts: "
           "7, random_markers: [25, 60], random_min_spacing: 0.05, "
           "random_share: 0.25, random_seed: 3}"));
  EXPECT_EQ(options.layouts, std::vector<std::string>{"cmu41"});
  EXPECT_EQ(options.random_layouts, 7);
  EXPECT_EQ(options.random_min_markers, 25);
  EXPECT_EQ(options.random_max_markers, 60);
  EXPECT_EQ(options.random_min_spacing, 0.05);
  EXPECT_EQ(options.random_share, 0.25);
  EXPECT_EQ(options.random_seed, 3u);
  EXPECT_NO_THROW(DecodeLayoutSamplerOptions(
      Yaml("{name: random, layouts: [], random_layouts: 4}")));
  for (const char* bad : {
           "{name: random, layouts: []}",
           "{name: random, random_layouts: 3}",  // listed layouts
           "{name: mixed, layouts: [cmu41]}",    // no pool
           "{name: builtin, random_layouts: 3}",
           "{name: mixed, random_layouts: 2, random_markers: [60, 30]}",
           "{name: mixed, random_layouts: 2, random_markers: [30, 200]}",
           "{name: mixed, random_layouts: 2, random_markers: [30]}",
           "{name: mixed, random_layouts: 2, random_share: 1.5}",
           "{name: other}",
       }) {
    EXPECT_THROW(DecodeLayoutSamplerOptions(Yaml(bad)), ConfigError) << bad;
  }
}

}  // namespace
}  // namespace soma
