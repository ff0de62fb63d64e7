// Per frame i of stream `seed` (REFERENCE.md 3.2-3.5):
//   rng = Rng(seed).Stream("frame").Stream(i), with named sub-streams
//   "shape"    betas_k = N(0, 1) * beta_stddev_k * shape_scale
//   "pose"     one motion frame, uniform over all frames of all clips
//   "rotation" delta ~ U(-pi, pi) about +Z applied to the root orientation
//              (translation not rotated, as SOMA's noisy_zrot)
//   "layout"   one training layout, uniform; other labels are zeroed
//   "noise"    the noise pipeline (each stage its own sub-stream)
// and the marker placement of block b = i / placement_block from
// Rng(seed).Stream("placement").Stream(b): per label one candidate vertex,
// uniform over [n-ring of each of its vertices..., its vertices...]
// (duplicates weigh more). internal::PlacedMarkerSampler is precomputed for
// the union of all candidates and poses only the chosen ones.
//
// With a layout sampler (SynthesisOptions::layout_sampler) the "layout"
// frame stream is unused: block b's layout is the sampler's Draw(seed, b),
// and its placement draws, from the same "placement" stream, one candidate
// per marker of that layout only (in marker order).
#include "framework/synth/synthesizer.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/synth/placed_markers.h"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <exception>
#include <map>
#include <numbers>
#include <thread>
#include <utility>

namespace soma {

void SynthesisOptions::Validate() const {
  auto fail = [](std::string_view key,
                 const std::string& value,
                 std::string_view constraint) {
    throw ConfigError(fmt::format(
        "Invalid configuration. synth.{} = {}. Violated constraint: {}",
        key,
        value,
        constraint));
  };
  if (marker_ring < 0 || marker_ring > 8) {
    fail("marker_ring", std::to_string(marker_ring), "0 <= marker_ring <= 8");
  }
  if (placement_block < 1) {
    fail("placement_block",
         std::to_string(placement_block),
         "placement_block >= 1");
  }
  if (!(shape_scale >= 0.0) || !std::isfinite(shape_scale)) {
    fail("shape_scale", FormatDouble(shape_scale), "shape_scale >= 0");
  }
  if (!(frame_rate > 0.0) || !std::isfinite(frame_rate)) {
    fail("frame_rate", FormatDouble(frame_rate), "frame_rate > 0");
  }
}

SynthesisOptions DecodeSynthesisOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  SynthesisOptions options;
  reader.Read("marker_ring", &options.marker_ring);
  reader.Read("placement_block", &options.placement_block);
  reader.Read("random_rotation", &options.random_rotation);
  reader.Read("shape_scale", &options.shape_scale);
  reader.Read("frame_rate", &options.frame_rate);
  reader.Read("layouts", &options.layouts);
  if (const ConfigNode* sampler = reader.Child("layout_sampler");
      sampler != nullptr && !sampler->IsNull()) {
    options.layout_sampler = DecodeLayoutSamplerOptions(*sampler);
  }
  reader.Check("marker_ring",
               options.marker_ring >= 0 && options.marker_ring <= 8,
               "0 <= marker_ring <= 8");
  reader.Check(
      "placement_block", options.placement_block >= 1, "placement_block >= 1");
  reader.Check("shape_scale", options.shape_scale >= 0, "shape_scale >= 0");
  reader.Check("frame_rate", options.frame_rate > 0, "frame_rate > 0");
  reader.Finish();
  options.Validate();
  return options;
}

struct Synthesizer::Impl {
  SynthesisOptions options;
  MarkerLayout superset;
  std::vector<std::string> labels;
  int num_points = 0;
  /// layout_masks[k][l]: label l is in training layout k.
  std::vector<std::vector<uint8_t>> layout_masks;
  /// Per label: candidate indices into the sampler's markers (duplicates
  /// weigh more).
  std::vector<std::vector<int>> candidates;
  std::unique_ptr<internal::PlacedMarkerSampler> sampler;
  std::vector<PoseSequence> motions;
  std::vector<int64_t> motion_offsets;  // cumulative frame counts, S + 1
  Eigen::VectorXd beta_scale;           // beta_stddev * shape_scale
  NoisePipeline noise;
  /// Layout-sampled frames only: the sampler, its slot table (candidates
  /// are then per table row) and the largest layout's marker count.
  std::unique_ptr<LayoutSampler> layout_sampler;
  SlotTable slot_table;
  int max_markers = 0;

  /// Scratch of one worker thread.
  struct Workspace {
    internal::PlacedMarkerSampler::Workspace sampler;
    internal::PlacedMarkerSampler::Selection selection;
    std::vector<float> markers;  // 3 x L
    Eigen::VectorXd betas;
    BodyPose pose;
    MarkerFrame frame;
    int64_t placement_block = -1;
    std::vector<int> placement;  // L candidate indices
    // Layout-sampled frames: the block's draw, marker -> slot, slot -> row.
    LayoutDraw draw;
    std::vector<int16_t> marker_slot;
    std::vector<int16_t> slot_rows;
  };

  /// Block `block`'s layout draw and the placement of its markers.
  void SampledPlacement(uint64_t seed, int64_t block, Workspace* ws) const {
    ws->draw = layout_sampler->Draw(seed, block);
    const int layout = ws->draw.layout;
    const int k = layout_sampler->layout(layout).num_markers();
    const int offset = layout_sampler->row_offset(layout);
    Rng rng =
        Rng(seed).Stream("placement").Stream(static_cast<uint64_t>(block));
    ws->placement.resize(static_cast<size_t>(k));
    for (int m = 0; m < k; ++m) {
      const std::vector<int>& list = candidates[offset + m];
      ws->placement[m] = list[static_cast<size_t>(
          rng.UniformInt(0, static_cast<int64_t>(list.size()) - 1))];
    }
    ws->marker_slot.assign(static_cast<size_t>(k), -1);
    for (size_t slot = 0; slot < ws->draw.slot_marker.size(); ++slot) {
      const int m = ws->draw.slot_marker[slot];
      if (m >= 0) ws->marker_slot[m] = static_cast<int16_t>(slot);
    }
    ws->slot_rows = layout_sampler->SlotRows(ws->draw);
  }

  /// A frame of block ws->draw's layout (docs of Synthesizer).
  void GenerateSampledFrame(const Rng& rng,
                            Workspace* ws,
                            float* out_points,
                            int16_t* out_labels,
                            int16_t* out_slots) const {
    const int k = static_cast<int>(ws->placement.size());
    ws->markers.resize(3 * static_cast<size_t>(k));
    sampler->Sample(
        ws->betas, ws->pose, ws->selection, &ws->sampler, ws->markers.data());
    MarkerFrame& frame = ws->frame;
    frame.Reset(k, noise.num_ghost_slots());
    for (int m = 0; m < k; ++m) {
      const float* p = &ws->markers[3 * static_cast<size_t>(m)];
      frame.Set(m, p[0], p[1], p[2], static_cast<int16_t>(m));
    }
    noise.Apply(&frame, rng.Stream("noise"));
    const int16_t null_slot = static_cast<int16_t>(labels.size());
    const int n = frame.num_points();
    std::copy(frame.points.begin(), frame.points.end(), out_points);
    std::fill(out_points + 3 * static_cast<size_t>(n),
              out_points + 3 * static_cast<size_t>(num_points),
              0.0f);
    for (int i = 0; i < n; ++i) {
      const int16_t label = frame.labels[i];
      out_labels[i] =
          label == frame.null_label() ? null_slot : ws->marker_slot[label];
    }
    std::fill(out_labels + n, out_labels + num_points, null_slot);
    std::copy(ws->slot_rows.begin(), ws->slot_rows.end(), out_slots);
  }

  void Placement(uint64_t seed, int64_t block, std::vector<int>* out) const {
    Rng rng =
        Rng(seed).Stream("placement").Stream(static_cast<uint64_t>(block));
    out->resize(candidates.size());
    for (size_t l = 0; l < candidates.size(); ++l) {
      const std::vector<int>& list = candidates[l];
      (*out)[l] = list[static_cast<size_t>(
          rng.UniformInt(0, static_cast<int64_t>(list.size()) - 1))];
    }
  }

  void GenerateFrame(uint64_t seed,
                     const Rng& frames_rng,
                     int64_t index,
                     Workspace* ws,
                     float* out_points,
                     int16_t* out_labels,
                     int16_t* out_slots) const {
    const int num_labels = static_cast<int>(labels.size());
    const int64_t block = index / options.placement_block;
    if (block != ws->placement_block) {
      if (layout_sampler) {
        SampledPlacement(seed, block, ws);
      } else {
        Placement(seed, block, &ws->placement);
      }
      sampler->Select(ws->placement, &ws->selection);
      ws->placement_block = block;
    }
    const Rng rng = frames_rng.Stream(static_cast<uint64_t>(index));

    Rng shape_rng = rng.Stream("shape");
    ws->betas.resize(beta_scale.size());
    for (Eigen::Index k = 0; k < beta_scale.size(); ++k) {
      ws->betas(k) = shape_rng.Normal() * beta_scale(k);
    }

    Rng pose_rng = rng.Stream("pose");
    const int64_t g = pose_rng.UniformInt(0, motion_offsets.back() - 1);
    const size_t s = static_cast<size_t>(
        std::upper_bound(motion_offsets.begin(), motion_offsets.end(), g) -
        motion_offsets.begin() - 1);
    const BodyPose& source = motions[s].frames[g - motion_offsets[s]];
    ws->pose.translation = source.translation;
    ws->pose.rotations = source.rotations;
    if (options.random_rotation) {
      Rng rotation_rng = rng.Stream("rotation");
      const double delta =
          rotation_rng.Uniform(-std::numbers::pi, std::numbers::pi);
      const Eigen::Vector3d root = ws->pose.rotations.col(0);
      const double angle = root.norm();
      const Eigen::Matrix3d root_rotation =
          angle > 0.0
              ? Eigen::AngleAxisd(angle, root / angle).toRotationMatrix()
              : Eigen::Matrix3d::Identity();
      const Eigen::AngleAxisd rotated(
          Eigen::AngleAxisd(delta, Eigen::Vector3d::UnitZ()) * root_rotation);
      ws->pose.rotations.col(0) = rotated.angle() * rotated.axis();
    }
    if (layout_sampler) {
      GenerateSampledFrame(rng, ws, out_points, out_labels, out_slots);
      return;
    }

    ws->markers.resize(3 * static_cast<size_t>(num_labels));
    sampler->Sample(
        ws->betas, ws->pose, ws->selection, &ws->sampler, ws->markers.data());

    int layout = 0;
    if (layout_masks.size() > 1) {
      Rng layout_rng = rng.Stream("layout");
      layout = static_cast<int>(layout_rng.UniformInt(
          0, static_cast<int64_t>(layout_masks.size()) - 1));
    }
    const std::vector<uint8_t>& mask = layout_masks[layout];
    MarkerFrame& frame = ws->frame;
    frame.Reset(num_labels, num_points - num_labels);
    for (int l = 0; l < num_labels; ++l) {
      if (!mask[l]) continue;
      const float* m = &ws->markers[3 * static_cast<size_t>(l)];
      frame.Set(l, m[0], m[1], m[2], static_cast<int16_t>(l));
    }
    noise.Apply(&frame, rng.Stream("noise"));
    std::copy(frame.points.begin(), frame.points.end(), out_points);
    std::copy(frame.labels.begin(), frame.labels.end(), out_labels);
  }
};

Synthesizer::Synthesizer(const BodyModel& body,
                         std::vector<MarkerLayout> layouts,
                         std::vector<PoseSequence> motions,
                         NoisePipeline noise,
                         const SynthesisOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Validate();
  Impl& impl = *impl_;
  impl.options = options;
  if (options.layout_sampler.has_value()) {
    LayoutSamplerOptions sampler_options = *options.layout_sampler;
    sampler_options.block_size = options.placement_block;
    impl.layout_sampler =
        std::make_unique<LayoutSampler>(body, std::move(sampler_options));
    impl.slot_table = impl.layout_sampler->BuildSlotTable();
    impl.max_markers = impl.layout_sampler->max_layout_markers();
    layouts.clear();
    for (int k = 0; k < impl.layout_sampler->num_layouts(); ++k) {
      layouts.push_back(impl.layout_sampler->layout(k));
    }
  }
  if (layouts.empty()) {
    throw ConfigError(
        "Synthesizer: no training layouts (give at least one marker layout)");
  }
  impl.superset = MergeLayouts(layouts);
  impl.labels = impl.superset.Labels();
  int num_labels = impl.superset.num_markers();
  if (num_labels == 0) {
    throw ConfigError("Synthesizer: the training layouts have no markers");
  }
  impl.noise = std::move(noise);
  if (impl.layout_sampler) {
    // Slots are the labels; the noise sees one sampled layout per frame.
    for (const MarkerLayout& layout : layouts) {
      impl.noise.Validate(layout.Labels());
    }
    num_labels = impl.layout_sampler->options().max_labels;
    impl.labels.clear();
    for (int slot = 0; slot < num_labels; ++slot) {
      impl.labels.push_back(fmt::format("slot{}", slot));
    }
    impl.num_points = impl.max_markers + impl.noise.num_ghost_slots();
  } else {
    impl.noise.Validate(impl.labels);
    impl.num_points = num_labels + impl.noise.num_ghost_slots();
  }
  if (impl.num_points > 32767) {
    throw ConfigError(fmt::format(
        "Synthesizer: {} points per frame do not fit int16 label ids",
        impl.num_points));
  }

  // Layout membership (labels canonicalised as MergeLayouts does); with a
  // layout sampler, layout k has the first K_k slots.
  for (size_t k = 0; k < layouts.size(); ++k) {
    std::vector<uint8_t> mask(num_labels, 0);
    if (impl.layout_sampler) {
      std::fill(mask.begin(), mask.begin() + layouts[k].num_markers(), 1);
      impl.layout_masks.push_back(std::move(mask));
      continue;
    }
    for (const MarkerLayout::Marker& m : layouts[k].markers) {
      const int l = impl.superset.FindLabel(CanonicalMarkerLabel(m.label));
      const int id = l >= 0 ? l : impl.superset.FindLabel(m.label);
      if (id < 0) {
        throw InternalError(fmt::format(
            "Synthesizer: label {} of layout {} is not in the superset",
            m.label,
            k));
      }
      mask[id] = 1;
    }
    impl.layout_masks.push_back(std::move(mask));
  }

  // Candidate vertices per label and their union (keyed by vertex and skin
  // distance).
  const int nv = body.num_vertices();
  std::vector<std::vector<int>> neighbours;
  if (options.marker_ring > 0) {
    neighbours = VertexNeighbours(nv, body.faces);
  }
  std::map<std::pair<int, double>, int> union_index;
  std::vector<int> union_vertices;
  std::vector<double> union_distances;
  // Candidates per label, or per slot-table row (the sampled layouts'
  // markers, concatenated) with a layout sampler.
  std::vector<MarkerLayout::Marker> candidate_markers;
  if (impl.layout_sampler) {
    for (const MarkerLayout& layout : layouts) {
      candidate_markers.insert(candidate_markers.end(),
                               layout.markers.begin(),
                               layout.markers.end());
    }
  }
  for (const MarkerLayout::Marker& m :
       impl.layout_sampler ? candidate_markers : impl.superset.markers) {
    if (m.vertex_ids.empty()) {
      throw ConfigError(
          fmt::format("Synthesizer: marker {} has no vertex id", m.label));
    }
    for (const int vid : m.vertex_ids) {
      if (vid < 0 || vid >= nv) {
        throw ShapeError(fmt::format(
            "Synthesizer: marker {} has vertex id {} outside [0, {}) of body "
            "'{}'",
            m.label,
            vid,
            nv,
            body.name));
      }
    }
    std::vector<int> list;
    if (options.marker_ring > 0 && m.type == "body") {
      for (const int vid : m.vertex_ids) {
        const std::vector<int> ring =
            NRing(neighbours, vid, options.marker_ring);
        list.insert(list.end(), ring.begin(), ring.end());
      }
    }
    list.insert(list.end(), m.vertex_ids.begin(), m.vertex_ids.end());
    std::vector<int> indices;
    indices.reserve(list.size());
    for (const int vid : list) {
      const auto key = std::make_pair(vid, m.distance_from_skin);
      auto it = union_index.find(key);
      if (it == union_index.end()) {
        it = union_index.emplace(key, static_cast<int>(union_vertices.size()))
                 .first;
        union_vertices.push_back(vid);
        union_distances.push_back(m.distance_from_skin);
      }
      indices.push_back(it->second);
    }
    impl.candidates.push_back(std::move(indices));
  }
  impl.sampler = std::make_unique<internal::PlacedMarkerSampler>(
      body, union_vertices, union_distances);

  // Motions.
  impl.motion_offsets.push_back(0);
  for (PoseSequence& sequence : motions) {
    if (sequence.frames.empty()) continue;
    for (const BodyPose& pose : sequence.frames) {
      if (pose.rotations.cols() != body.num_joints() ||
          pose.rotations.rows() != 3) {
        throw ShapeError(fmt::format(
            "Synthesizer: motion '{}' has poses with {} x {} rotations, body "
            "'{}' needs 3 x {}",
            sequence.name,
            pose.rotations.rows(),
            pose.rotations.cols(),
            body.name,
            body.num_joints()));
      }
    }
    impl.motion_offsets.push_back(impl.motion_offsets.back() +
                                  sequence.num_frames());
    impl.motions.push_back(std::move(sequence));
  }
  if (impl.motions.empty()) {
    throw ConfigError(
        "Synthesizer: no motion frames (the motion source gave no non-empty "
        "clip for this split)");
  }

  // Shape prior.
  impl.beta_scale = Eigen::VectorXd::Zero(body.num_betas());
  for (int k = 0; k < body.num_betas(); ++k) {
    const double stddev =
        k < body.beta_stddev.size() ? body.beta_stddev(k) : 1.0;
    impl.beta_scale(k) = stddev * options.shape_scale;
  }
}

Synthesizer::~Synthesizer() = default;
Synthesizer::Synthesizer(Synthesizer&&) noexcept = default;
Synthesizer& Synthesizer::operator=(Synthesizer&&) noexcept = default;

const std::vector<std::string>& Synthesizer::labels() const {
  return impl_->labels;
}
int Synthesizer::num_labels() const {
  return static_cast<int>(impl_->labels.size());
}
int Synthesizer::num_points() const { return impl_->num_points; }
const MarkerLayout& Synthesizer::superset() const { return impl_->superset; }
const NoisePipeline& Synthesizer::noise() const { return impl_->noise; }
const SynthesisOptions& Synthesizer::options() const { return impl_->options; }
int Synthesizer::num_layouts() const {
  return static_cast<int>(impl_->layout_masks.size());
}
bool Synthesizer::LayoutHasLabel(int layout, int label) const {
  return impl_->layout_masks.at(layout).at(label) != 0;
}
int64_t Synthesizer::num_motion_frames() const {
  return impl_->motion_offsets.back();
}
double Synthesizer::frame_rate() const {
  return impl_->motions.front().frame_rate;
}
int Synthesizer::num_candidate_markers() const {
  return impl_->sampler->num_candidates();
}
const SlotTable* Synthesizer::slot_table() const {
  return impl_->layout_sampler ? &impl_->slot_table : nullptr;
}
const LayoutSampler* Synthesizer::layout_sampler() const {
  return impl_->layout_sampler.get();
}

void Synthesizer::Generate(uint64_t seed,
                           int64_t first,
                           int64_t count,
                           LabeledFrames* out,
                           int threads) const {
  if (out == nullptr) throw InternalError("Synthesizer::Generate: out is null");
  if (first < 0 || count < 0) {
    throw ShapeError(fmt::format(
        "Synthesizer::Generate: frames [{}, {} + {}) (need first, count >= 0)",
        first,
        first,
        count));
  }
  const Impl& impl = *impl_;
  const int n = impl.num_points;
  out->num_points = n;
  out->points.resize(static_cast<size_t>(count) * n * 3);
  out->labels.resize(static_cast<size_t>(count) * n);
  out->num_slots =
      impl.layout_sampler ? impl.layout_sampler->options().max_labels : 0;
  out->slots.resize(static_cast<size_t>(count) * out->num_slots);
  if (count == 0) return;
  const Rng frames_rng = Rng(seed).Stream("frame");
  const int workers = static_cast<int>(
      std::clamp<int64_t>(threads, 1, std::max<int64_t>(1, count / 64)));
  auto run = [&](int64_t begin, int64_t end) {
    Impl::Workspace ws;
    for (int64_t f = begin; f < end; ++f) {
      impl.GenerateFrame(seed,
                         frames_rng,
                         first + f,
                         &ws,
                         out->frame_points(f),
                         out->frame_labels(f),
                         out->frame_slots(f));
    }
  };
  if (workers == 1) {
    run(0, count);
    return;
  }
  std::vector<std::exception_ptr> errors(workers);
  std::vector<std::thread> pool;
  auto chunk_begin = [&](int t) { return count * t / workers; };
  for (int t = 1; t < workers; ++t) {
    pool.emplace_back([&, t] {
      try {
        run(chunk_begin(t), chunk_begin(t + 1));
      } catch (...) {
        errors[t] = std::current_exception();
      }
    });
  }
  try {
    run(chunk_begin(0), chunk_begin(1));
  } catch (...) {
    errors[0] = std::current_exception();
  }
  for (std::thread& thread : pool) thread.join();
  for (const std::exception_ptr& error : errors) {
    if (error) std::rethrow_exception(error);
  }
}

}  // namespace soma
