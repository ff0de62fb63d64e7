#include "framework/synth/synthesizer.h"

#include "framework/body/marker_layout.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/random.h"
#include "framework/registry/registry.h"
#include "framework/testing/body_fixture.h"
#include "framework/testing/testing.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <set>
#include <string>
#include <vector>

namespace soma {

namespace {

using ::soma::testing::ProceduralBody;

NoisePipeline Noise(const std::string& yaml) {
  BuildContext ctx;
  return BuildNoisePipeline(ParseYaml(yaml, "test.yaml"), ctx);
}

constexpr const char* kBCG = R"(
modules:
  - {name: occlusion, max_count: 5}
  - {name: ghosts, distribution: spherical_gaussian, max_count: 3}
  - {name: permutation}
)";

const MarkerLayout& Cmu41() {
  static const MarkerLayout layout =
      MakeBuiltinLayout(ProceduralBody(), "cmu41");
  return layout;
}

std::vector<PoseSequence> RandomMotions(int sequences, int frames) {
  const BodyModel& body = ProceduralBody();
  Rng rng(11);
  std::vector<PoseSequence> motions;
  for (int s = 0; s < sequences; ++s) {
    PoseSequence sequence;
    sequence.name = "random_" + std::to_string(s);
    for (int f = 0; f < frames; ++f) {
      BodyPose pose = BodyPose::Rest(body.num_joints());
      for (int j = 0; j < body.num_joints(); ++j) {
        for (int c = 0; c < 3; ++c) pose.rotations(c, j) = 0.2 * rng.Normal();
      }
      pose.translation = Eigen::Vector3d(rng.Normal(), rng.Normal(), 0.0);
      sequence.frames.push_back(pose);
    }
    motions.push_back(std::move(sequence));
  }
  return motions;
}

Synthesizer MakeSynthesizer(const std::string& noise = kBCG,
                            const SynthesisOptions& options = {},
                            std::vector<MarkerLayout> layouts = {Cmu41()}) {
  return Synthesizer(ProceduralBody(),
                     std::move(layouts),
                     RandomMotions(3, 20),
                     Noise(noise),
                     options);
}

bool SameFrames(const LabeledFrames& a,
                int64_t a_first,
                const LabeledFrames& b,
                int64_t b_first,
                int64_t count) {
  if (a.num_points != b.num_points) return false;
  const int n = a.num_points;
  return std::memcmp(a.frame_points(a_first),
                     b.frame_points(b_first),
                     sizeof(float) * 3 * n * count) == 0 &&
         std::memcmp(a.frame_labels(a_first),
                     b.frame_labels(b_first),
                     sizeof(int16_t) * n * count) == 0;
}

TEST(Synthesizer, SizesAndLabels) {
  const Synthesizer synth = MakeSynthesizer();
  EXPECT_EQ(synth.num_labels(), 41);
  EXPECT_EQ(synth.num_points(), 44);
  EXPECT_EQ(synth.labels(), Cmu41().Labels());
  EXPECT_EQ(synth.num_layouts(), 1);
  EXPECT_EQ(synth.num_motion_frames(), 60);
  // Ring-1 candidates: far more positions than labels.
  EXPECT_GT(synth.num_candidate_markers(), 4 * 41);
  LabeledFrames frames;
  synth.Generate(1, 0, 500, &frames);
  ASSERT_EQ(frames.num_points, 44);
  ASSERT_EQ(frames.num_frames(), 500);
  int missing_markers = 0;
  for (int64_t f = 0; f < 500; ++f) {
    std::vector<int> seen(41, 0);
    for (int p = 0; p < 44; ++p) {
      const int label = frames.frame_labels(f)[p];
      const float* x = frames.frame_points(f) + 3 * p;
      const bool present = x[0] != 0 || x[1] != 0 || x[2] != 0;
      ASSERT_GE(label, 0);
      ASSERT_LE(label, 41);
      if (!present) {
        ASSERT_EQ(label, 41);
      }
      if (label < 41) ++seen[label];
    }
    for (int l = 0; l < 41; ++l) {
      ASSERT_LE(seen[l], 1);
      missing_markers += 1 - seen[l];
    }
  }
  // Up to 5 occlusions: 2.5 per frame on average.
  EXPECT_NEAR(missing_markers / 500.0, 2.5, 0.3);
}

TEST(Synthesizer, SameSeedGivesByteIdenticalFramesAtAnyThreadCount) {
  const Synthesizer synth = MakeSynthesizer();
  LabeledFrames a, b, c, d;
  synth.Generate(42, 0, 1000, &a, 1);
  synth.Generate(42, 0, 1000, &b, 1);
  synth.Generate(42, 0, 1000, &c, 3);
  synth.Generate(43, 0, 1000, &d, 2);
  EXPECT_TRUE(SameFrames(a, 0, b, 0, 1000));
  EXPECT_TRUE(SameFrames(a, 0, c, 0, 1000));
  EXPECT_FALSE(SameFrames(a, 0, d, 0, 1000));
  // A second synthesizer from the same inputs agrees too.
  LabeledFrames e;
  MakeSynthesizer().Generate(42, 0, 1000, &e, 2);
  EXPECT_TRUE(SameFrames(a, 0, e, 0, 1000));
}

TEST(Synthesizer, SmallDatasetMatchesItsGoldenHash) {
  // Pinned across builds: 200 frames of cmu41 + B+C+G from seed 42 hash to
  // the value below (FNV-1a over the points' and labels' bytes). A change
  // of the body, the layout, the motion sampling, the noise modules or the
  // RNG shows here; update the value only on purpose, and say why.
  LabeledFrames frames;
  MakeSynthesizer().Generate(42, 0, 200, &frames, 2);
  const int64_t n = frames.num_points;
  const std::string_view points(
      reinterpret_cast<const char*>(frames.frame_points(0)),
      sizeof(float) * 3 * n * 200);
  const std::string_view labels(
      reinterpret_cast<const char*>(frames.frame_labels(0)),
      sizeof(int16_t) * n * 200);
  EXPECT_EQ(n, 44);
  EXPECT_EQ(Fnv1a64(labels, Fnv1a64(points)), 13854889672415331381u);
}

TEST(Synthesizer, FrameDependsOnlyOnSeedAndIndex) {
  SynthesisOptions options;
  options.placement_block = 4;  // ranges below cross placement blocks
  const Synthesizer synth = MakeSynthesizer(kBCG, options);
  LabeledFrames all, part, late;
  synth.Generate(5, 0, 10, &all);
  synth.Generate(5, 5, 3, &part);
  EXPECT_TRUE(SameFrames(all, 5, part, 0, 3));
  synth.Generate(5, 1000003, 2, &late, 2);
  LabeledFrames late_one;
  synth.Generate(5, 1000004, 1, &late_one);
  EXPECT_TRUE(SameFrames(late, 1, late_one, 0, 1));
  LabeledFrames empty;
  synth.Generate(5, 0, 0, &empty);
  EXPECT_EQ(empty.num_frames(), 0);
  EXPECT_THROW(synth.Generate(5, -1, 2, &empty), ShapeError);
}

TEST(Synthesizer, CleanMarkersMatchTheFullMeshAtMeanShape) {
  // No noise, no ring, no rotation, mean shape: the layout's markers exactly.
  SynthesisOptions options;
  options.marker_ring = 0;
  options.random_rotation = false;
  options.shape_scale = 0.0;
  std::vector<PoseSequence> motions = RandomMotions(1, 1);
  const BodyPose pose = motions[0].frames[0];
  const Synthesizer synth(
      ProceduralBody(), {Cmu41()}, motions, NoisePipeline(), options);
  EXPECT_EQ(synth.num_points(), 41);
  LabeledFrames frames;
  synth.Generate(9, 0, 3, &frames);
  const Eigen::Matrix3Xd v =
      PoseVertices(ProceduralBody(),
                   Eigen::VectorXd::Zero(ProceduralBody().num_betas()),
                   pose);
  const Eigen::Matrix3Xd expected =
      MarkerPositions(Cmu41(), v, VertexNormals(v, ProceduralBody().faces));
  for (int64_t f = 0; f < 3; ++f) {
    for (int l = 0; l < 41; ++l) {
      EXPECT_EQ(frames.frame_labels(f)[l], l);
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(frames.frame_points(f)[3 * l + c], expected(c, l), 1e-4);
      }
    }
  }
}

TEST(Synthesizer, RandomPlacementPicksRingVerticesExactly) {
  // Ring 1, mean shape, no rotation: every marker is the full-mesh marker of
  // one of its label's candidate vertices (the vertex or its 1-ring).
  SynthesisOptions options;
  options.random_rotation = false;
  options.shape_scale = 0.0;
  options.placement_block = 1;
  std::vector<PoseSequence> motions = RandomMotions(1, 1);
  const BodyModel& body = ProceduralBody();
  const Synthesizer synth(body, {Cmu41()}, motions, NoisePipeline(), options);
  LabeledFrames frames;
  synth.Generate(21, 0, 20, &frames);
  const Eigen::Matrix3Xd v = PoseVertices(
      body, Eigen::VectorXd::Zero(body.num_betas()), motions[0].frames[0]);
  const Eigen::Matrix3Xd normals = VertexNormals(v, body.faces);
  const auto neighbours = VertexNeighbours(body.num_vertices(), body.faces);
  std::set<int> chosen_other_than_layout;
  for (int l = 0; l < 41; ++l) {
    const int vid = Cmu41().markers[l].vertex_ids[0];
    std::vector<int> candidates = NRing(neighbours, vid, 1);
    candidates.push_back(vid);
    for (int64_t f = 0; f < 20; ++f) {
      const Eigen::Map<const Eigen::Vector3f> p(frames.frame_points(f) + 3 * l);
      double best = 1e9;
      int best_vid = -1;
      for (const int c : candidates) {
        const Eigen::Vector3d q =
            v.col(c) + normals.col(c) * Cmu41().markers[l].distance_from_skin;
        const double d = (p.cast<double>() - q).norm();
        if (d < best) {
          best = d;
          best_vid = c;
        }
      }
      EXPECT_LT(best, 1e-4) << l << " " << f;
      if (best_vid != vid) chosen_other_than_layout.insert(l);
    }
  }
  EXPECT_GT(chosen_other_than_layout.size(), 30u);
}

TEST(Synthesizer, RandomRotationIsAboutTheVerticalAxisThroughTheRoot) {
  SynthesisOptions options;
  options.marker_ring = 0;
  options.shape_scale = 0.0;
  std::vector<PoseSequence> motions = RandomMotions(1, 1);
  const BodyModel& body = ProceduralBody();
  const Synthesizer synth(body, {Cmu41()}, motions, NoisePipeline(), options);
  SynthesisOptions fixed = options;
  fixed.random_rotation = false;
  const Synthesizer reference(body, {Cmu41()}, motions, NoisePipeline(), fixed);
  LabeledFrames rotated, upright;
  synth.Generate(3, 0, 200, &rotated);
  reference.Generate(3, 0, 1, &upright);
  // Root joint position (rotation centre).
  const Eigen::Matrix3Xd rest = body.RestJoints(body.template_vertices);
  const PosedSkeleton skeleton = PoseSkeleton(body, rest, motions[0].frames[0]);
  const Eigen::Vector3d root = skeleton.global[0].translation();
  std::vector<double> angles;
  for (int64_t f = 0; f < 200; ++f) {
    for (int l = 0; l < 41; ++l) {
      const float* p = rotated.frame_points(f) + 3 * l;
      const float* q = upright.frame_points(0) + 3 * l;
      EXPECT_NEAR(p[2], q[2], 1e-4);
      const double rp = std::hypot(p[0] - root(0), p[1] - root(1));
      const double rq = std::hypot(q[0] - root(0), q[1] - root(1));
      EXPECT_NEAR(rp, rq, 1e-4);
    }
    const float* p = rotated.frame_points(f);
    const float* q = upright.frame_points(0);
    angles.push_back(std::atan2(p[1] - root(1), p[0] - root(0)) -
                     std::atan2(q[1] - root(1), q[0] - root(0)));
  }
  // Angles spread over the circle: mean resultant length near 0.
  double cs = 0.0;
  double sn = 0.0;
  for (const double a : angles) {
    cs += std::cos(a) / angles.size();
    sn += std::sin(a) / angles.size();
  }
  EXPECT_LT(std::hypot(cs, sn), 0.2);
}

TEST(Synthesizer, PlacementIsSharedWithinABlock) {
  SynthesisOptions options;
  options.random_rotation = false;
  options.shape_scale = 0.0;
  options.placement_block = 8;
  std::vector<PoseSequence> motions = RandomMotions(1, 1);
  const Synthesizer synth(
      ProceduralBody(), {Cmu41()}, motions, NoisePipeline(), options);
  LabeledFrames frames;
  synth.Generate(4, 0, 32, &frames);
  for (int64_t f = 0; f < 32; ++f) {
    const int64_t first_of_block = (f / 8) * 8;
    EXPECT_TRUE(SameFrames(frames, f, frames, first_of_block, 1)) << f;
  }
  int distinct_blocks = 0;
  for (int64_t b = 1; b < 4; ++b) {
    distinct_blocks += SameFrames(frames, 0, frames, 8 * b, 1) ? 0 : 1;
  }
  EXPECT_GE(distinct_blocks, 2);
  // Markers stay close to the layout's vertex (1-ring: a few cm).
  options.marker_ring = 0;
  const Synthesizer fixed(
      ProceduralBody(), {Cmu41()}, motions, NoisePipeline(), options);
  LabeledFrames reference;
  fixed.Generate(4, 0, 1, &reference);
  for (int64_t f = 0; f < 32; f += 8) {
    for (int l = 0; l < 41; ++l) {
      const Eigen::Map<const Eigen::Vector3f> p(frames.frame_points(f) + 3 * l);
      const Eigen::Map<const Eigen::Vector3f> q(reference.frame_points(0) +
                                                3 * l);
      EXPECT_LT((p - q).norm(), 0.06) << l;
    }
  }
}

TEST(Synthesizer, ShapesVary) {
  SynthesisOptions options;
  options.random_rotation = false;
  options.marker_ring = 0;
  std::vector<PoseSequence> motions = RandomMotions(1, 1);
  const Synthesizer synth(
      ProceduralBody(), {Cmu41()}, motions, NoisePipeline(), options);
  LabeledFrames frames;
  synth.Generate(4, 0, 50, &frames);
  // Height of the highest marker varies with the body shape.
  std::vector<float> top;
  for (int64_t f = 0; f < 50; ++f) {
    float z = -1e9f;
    for (int l = 0; l < 41; ++l)
      z = std::max(z, frames.frame_points(f)[3 * l + 2]);
    top.push_back(z);
  }
  const auto [lo, hi] = std::minmax_element(top.begin(), top.end());
  EXPECT_GT(*hi - *lo, 0.02);
}

TEST(Synthesizer, LayoutSubsettingUsesOneTrainingLayoutPerFrame) {
  const MarkerLayout pig = MakeBuiltinLayout(ProceduralBody(), "pig39");
  const Synthesizer synth = MakeSynthesizer("modules: []", {}, {Cmu41(), pig});
  ASSERT_EQ(synth.num_layouts(), 2);
  EXPECT_EQ(synth.superset().num_markers(), synth.num_labels());
  EXPECT_GT(synth.num_labels(), 41);
  std::set<int> sizes[2];
  for (int k = 0; k < 2; ++k) {
    int size = 0;
    for (int l = 0; l < synth.num_labels(); ++l)
      size += synth.LayoutHasLabel(k, l) ? 1 : 0;
    sizes[k].insert(size);
  }
  LabeledFrames frames;
  synth.Generate(8, 0, 400, &frames);
  int used[2] = {0, 0};
  for (int64_t f = 0; f < 400; ++f) {
    int layout = -1;
    for (int k = 0; k < 2 && layout < 0; ++k) {
      bool match = true;
      for (int l = 0; l < synth.num_labels(); ++l) {
        const float* p = frames.frame_points(f) + 3 * l;
        const bool present = p[0] != 0 || p[1] != 0 || p[2] != 0;
        match &= present == synth.LayoutHasLabel(k, l);
        if (present) match &= frames.frame_labels(f)[l] == l;
      }
      if (match) layout = k;
    }
    ASSERT_GE(layout, 0) << f;
    ++used[layout];
  }
  EXPECT_NEAR(used[0], 200, 50);
  EXPECT_NEAR(used[1], 200, 50);
}

TEST(Synthesizer, ExtremeGhostsPadToSixtySlots) {
  const Synthesizer synth = MakeSynthesizer(R"(
modules:
  - {name: ghosts, max_count: 60, exact: true, up_to: false}
  - {name: permutation}
)");
  EXPECT_EQ(synth.num_points(), 101);
  LabeledFrames frames;
  synth.Generate(2, 0, 10, &frames);
  for (int64_t f = 0; f < 10; ++f) {
    EXPECT_EQ(std::count(frames.frame_labels(f),
                         frames.frame_labels(f) + 101,
                         static_cast<int16_t>(41)),
              60);
  }
}

TEST(Synthesizer, BadInputIsAClearError) {
  const BodyModel& body = ProceduralBody();
  EXPECT_THROW(Synthesizer(body, {}, RandomMotions(1, 2), NoisePipeline()),
               ConfigError);
  EXPECT_THROW(Synthesizer(body, {Cmu41()}, {}, NoisePipeline()), ConfigError);
  std::vector<PoseSequence> empty(1);
  EXPECT_THROW(Synthesizer(body, {Cmu41()}, empty, NoisePipeline()),
               ConfigError);
  std::vector<PoseSequence> wrong = RandomMotions(1, 2);
  wrong[0].frames[1].rotations.resize(3, 5);
  EXPECT_THROW(Synthesizer(body, {Cmu41()}, wrong, NoisePipeline()),
               ShapeError);
  const std::string message = testing::ErrorMessage<ConfigError>([&] {
    Synthesizer(body,
                {Cmu41()},
                RandomMotions(1, 2),
                Noise("modules: [{name: occlusion, max_count: 42}]"));
  });
  EXPECT_NE(message.find("max_count = 42"), std::string::npos) << message;
  SynthesisOptions options;
  options.placement_block = 0;
  EXPECT_THROW(
      Synthesizer(
          body, {Cmu41()}, RandomMotions(1, 2), NoisePipeline(), options),
      ConfigError);
  MarkerLayout bad = Cmu41();
  bad.markers[0].vertex_ids = {body.num_vertices() + 5};
  EXPECT_THROW(Synthesizer(body, {bad}, RandomMotions(1, 2), NoisePipeline()),
               ShapeError);
}

TEST(SynthesisOptions, DecodeReadsEveryKeyAndRejectsUnknownOnes) {
  const SynthesisOptions options = DecodeSynthesisOptions(
      ParseYaml("{marker_ring: 2, placement_block: 16, random_rotation: false, "
                "shape_scale: 0.5, frame_rate: 60, layouts: [cmu41, pig39]}",
                "synth.yaml"));
  EXPECT_EQ(options.marker_ring, 2);
  EXPECT_EQ(options.placement_block, 16);
  EXPECT_FALSE(options.random_rotation);
  EXPECT_EQ(options.shape_scale, 0.5);
  EXPECT_EQ(options.frame_rate, 60.0);
  EXPECT_EQ(options.layouts, (std::vector<std::string>{"cmu41", "pig39"}));
  EXPECT_THROW(DecodeSynthesisOptions(ParseYaml("{ring: 1}", "s.yaml")),
               ConfigError);
  const std::string message = testing::ErrorMessage<ConfigError>([] {
    DecodeSynthesisOptions(ParseYaml("{placement_block: 0}", "s.yaml"));
  });
  EXPECT_NE(message.find("placement_block"), std::string::npos) << message;
}

// Layout-sampled frames (docs/any_layout_design.md, "The data").
SynthesisOptions SampledOptions(int marker_ring) {
  SynthesisOptions options;
  options.marker_ring = marker_ring;
  LayoutSamplerOptions sampler;
  sampler.layouts = {"cmu41", "pig39", "soma53"};
  sampler.max_labels = 60;
  options.layout_sampler = sampler;
  return options;
}

TEST(Synthesizer, LayoutSamplerLabelsEachBlockWithItsOwnLayoutsSlots) {
  const Synthesizer synth = MakeSynthesizer(kBCG, SampledOptions(1));
  ASSERT_NE(synth.layout_sampler(), nullptr);
  ASSERT_NE(synth.slot_table(), nullptr);
  EXPECT_EQ(synth.num_labels(), 60);
  EXPECT_EQ(synth.num_points(), 53 + 3);  // largest layout + ghost slots
  const SlotTable& table = *synth.slot_table();
  EXPECT_EQ(table.num_rows(), 41 + 39 + 53);
  EXPECT_EQ(table.width, synth.layout_sampler()->descriptor_width());
  const int64_t frames_count = 320;
  LabeledFrames frames;
  synth.Generate(5, 0, frames_count, &frames, 2);
  ASSERT_EQ(frames.num_slots, 60);
  ASSERT_EQ(frames.num_frames(), frames_count);
  std::set<int> layouts_drawn;
  for (int64_t f = 0; f < frames_count; ++f) {
    const LayoutSampler& sampler = *synth.layout_sampler();
    const LayoutDraw draw = sampler.Draw(5, f / 32);
    layouts_drawn.insert(draw.layout);
    const int k = sampler.layout(draw.layout).num_markers();
    const std::vector<int16_t> rows = sampler.SlotRows(draw);
    ASSERT_TRUE(std::equal(rows.begin(), rows.end(), frames.frame_slots(f)))
        << "frame " << f;
    std::vector<int> seen(60, 0);
    int labelled = 0;
    for (int p = 0; p < synth.num_points(); ++p) {
      const int label = frames.frame_labels(f)[p];
      const float* x = frames.frame_points(f) + 3 * p;
      const bool present = x[0] != 0 || x[1] != 0 || x[2] != 0;
      ASSERT_GE(label, 0);
      ASSERT_LE(label, 60);
      if (!present) {
        ASSERT_EQ(label, 60);
      }
      if (label == 60) continue;
      // A label is a slot of this block's draw, a row of its own layout.
      ASSERT_GE(rows[label], 0) << "frame " << f << " slot " << label;
      ASSERT_EQ(table.row_layout[rows[label]], draw.layout);
      ASSERT_EQ(++seen[label], 1);
      ++labelled;
    }
    ASSERT_LE(labelled, k);
    ASSERT_GE(labelled, k - 5);  // occlusion: at most 5
  }
  EXPECT_GE(layouts_drawn.size(), 2u);
}

TEST(Synthesizer, RandomLayoutPoolFramesCarryTheirLayoutsSlots) {
  SynthesisOptions options = SampledOptions(1);
  options.layout_sampler->random_layouts = 6;
  options.layout_sampler->random_min_markers = 30;
  options.layout_sampler->random_max_markers = 58;
  const Synthesizer synth = MakeSynthesizer(kBCG, options);
  const LayoutSampler& sampler = *synth.layout_sampler();
  const SlotTable& table = *synth.slot_table();
  ASSERT_EQ(table.layouts.back(), "random");
  int pool_frames = 0;
  LabeledFrames frames;
  synth.Generate(2, 0, 640, &frames, 2);
  for (int64_t f = 0; f < 640; ++f) {
    const LayoutDraw draw = sampler.Draw(2, f / 32);
    const int k = sampler.layout(draw.layout).num_markers();
    pool_frames += draw.layout >= sampler.num_listed() ? 1 : 0;
    int labelled = 0;
    for (int p = 0; p < synth.num_points(); ++p) {
      const int slot = frames.frame_labels(f)[p];
      if (slot == 60) continue;
      const int row = frames.frame_slots(f)[slot];
      ASSERT_GE(row, 0) << "frame " << f << " slot " << slot;
      ASSERT_EQ(table.row_layout[row], sampler.group(draw.layout));
      ++labelled;
    }
    ASSERT_LE(labelled, k);
    ASSERT_GE(labelled, k - 5);
  }
  EXPECT_GT(pool_frames, 0);
  EXPECT_LT(pool_frames, 640);
}

TEST(Synthesizer, LayoutSamplerPlacesTheDrawnLayoutsMarkers) {
  // Without ring jitter and noise, a sampled frame of layout k holds the
  // markers a synthesizer of that layout alone makes for the same frame
  // (same shape, pose and rotation streams; its labels sorted by
  // MergeLayouts), and each slot label names the marker at that point.
  const std::string no_noise = "modules: []";
  const Synthesizer sampled = MakeSynthesizer(no_noise, SampledOptions(0));
  SynthesisOptions fixed_options;
  fixed_options.marker_ring = 0;
  const LayoutSampler& sampler = *sampled.layout_sampler();
  const SlotTable& table = *sampled.slot_table();
  std::vector<Synthesizer> fixed;
  fixed.reserve(static_cast<size_t>(sampler.num_layouts()));
  for (int k = 0; k < sampler.num_layouts(); ++k) {
    fixed.push_back(
        MakeSynthesizer(no_noise, fixed_options, {sampler.layout(k)}));
  }
  LabeledFrames frames;
  sampled.Generate(9, 0, 256, &frames);
  int checked = 0;
  for (int64_t f = 0; f < 256; f += 7) {
    const LayoutDraw draw = sampler.Draw(9, f / 32);
    const Synthesizer& alone = fixed[draw.layout];
    LabeledFrames one;
    alone.Generate(9, f, 1, &one);
    const int k = sampler.layout(draw.layout).num_markers();
    ASSERT_EQ(one.num_points, k);
    int labelled = 0;
    for (int p = 0; p < sampled.num_points(); ++p) {
      const int slot = frames.frame_labels(f)[p];
      const float* x = frames.frame_points(f) + 3 * p;
      if (slot == 60) {
        ASSERT_GE(p, k);  // only the padding of a smaller layout is empty
        continue;
      }
      const int row = frames.frame_slots(f)[slot];
      ASSERT_GE(row, 0);
      const std::string name = CanonicalMarkerLabel(table.names[row]);
      const int id = alone.superset().FindLabel(name);
      ASSERT_GE(id, 0) << name;
      int at = -1;
      for (int q = 0; q < k; ++q) {
        if (one.frame_labels(0)[q] == id) at = q;
      }
      ASSERT_GE(at, 0) << name;
      for (int c = 0; c < 3; ++c) {  // exactly the same coordinates
        ASSERT_EQ(x[c], one.frame_points(0)[3 * at + c])
            << "frame " << f << " marker " << name;
      }
      ++labelled;
    }
    ASSERT_EQ(labelled, k);
    ++checked;
  }
  EXPECT_EQ(checked, 37);
}

TEST(Synthesizer, LayoutSampledFramesAreDeterministic) {
  const Synthesizer synth = MakeSynthesizer(kBCG, SampledOptions(1));
  LabeledFrames a, b, c;
  synth.Generate(3, 0, 200, &a, 1);
  synth.Generate(3, 0, 200, &b, 3);
  synth.Generate(3, 100, 50, &c, 1);  // frame i depends on (seed, i) only
  EXPECT_TRUE(SameFrames(a, 0, b, 0, 200));
  EXPECT_EQ(a.slots, b.slots);
  EXPECT_TRUE(SameFrames(a, 100, c, 0, 50));
  EXPECT_TRUE(std::equal(c.slots.begin(), c.slots.end(), a.frame_slots(100)));
  // Default synthesis carries no slots.
  LabeledFrames plain;
  MakeSynthesizer().Generate(3, 0, 10, &plain);
  EXPECT_EQ(plain.num_slots, 0);
  EXPECT_TRUE(plain.slots.empty());
}

TEST(Synthesizer, LayoutSamplerBadInputIsOneLine) {
  SynthesisOptions options = SampledOptions(1);
  options.layout_sampler->max_labels = 50;  // soma53 does not fit
  const std::string message = testing::ErrorMessage<ConfigError>(
      [&] { MakeSynthesizer(kBCG, options); });
  EXPECT_NE(message.find("soma53"), std::string::npos) << message;
  EXPECT_NE(message.find("50"), std::string::npos) << message;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
}

TEST(SynthesisOptions, DecodesALayoutSampler) {
  const SynthesisOptions options = DecodeSynthesisOptions(
      ParseYaml("{layout_sampler: {name: builtin, layouts: [pig39, soma53], "
                "max_labels: 64, shuffle_slots: false}}",
                "synth.yaml"));
  ASSERT_TRUE(options.layout_sampler.has_value());
  EXPECT_EQ(options.layout_sampler->layouts,
            (std::vector<std::string>{"pig39", "soma53"}));
  EXPECT_EQ(options.layout_sampler->max_labels, 64);
  EXPECT_FALSE(options.layout_sampler->shuffle_slots);
  EXPECT_FALSE(DecodeSynthesisOptions(ParseYaml("{layout_sampler: null}", "s"))
                   .layout_sampler.has_value());
  EXPECT_THROW(DecodeSynthesisOptions(
                   ParseYaml("{layout_sampler: {name: random}}", "s.yaml")),
               ConfigError);
  EXPECT_THROW(DecodeSynthesisOptions(ParseYaml(
                   "{layout_sampler: {name: builtin, size: 3}}", "s.yaml")),
               ConfigError);
}

}  // namespace
}  // namespace soma
