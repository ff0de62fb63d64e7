#include "framework/synth/layout_sampler.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <algorithm>
#include <utility>

namespace soma {

void LayoutSamplerOptions::Validate() const {
  auto fail = [](std::string_view key,
                 const std::string& value,
                 std::string_view constraint) {
    throw ConfigError(
        fmt::format("Invalid configuration. layout_sampler.{} = {}. Violated "
                    "constraint: {}",
                    key,
                    value,
                    constraint));
  };
  if (layouts.empty() && random_layouts == 0) {
    fail("layouts", "[]", "at least one layout (or random_layouts > 0)");
  }
  if (max_labels <= 0) {
    fail("max_labels", std::to_string(max_labels), "max_labels > 0");
  }
  if (block_size <= 0) {
    fail("block_size", std::to_string(block_size), "block_size > 0");
  }
  if (random_layouts < 0) {
    fail("random_layouts",
         std::to_string(random_layouts),
         "random_layouts >= 0");
  }
  if (perturbed_layouts < 0) {
    fail("perturbed_layouts",
         std::to_string(perturbed_layouts),
         "perturbed_layouts >= 0");
  }
  if (perturbed_layouts > 0) {
    if (layouts.empty()) {
      fail("perturbed_layouts",
           std::to_string(perturbed_layouts),
           "listed layouts to perturb (layouts is empty)");
    }
    if (!(perturb_keep > 0 && perturb_keep <= 1)) {
      fail("perturb_keep",
           fmt::format("{}", perturb_keep),
           "0 < perturb_keep <= 1");
    }
    if (perturb_rings < 0 || perturb_rings > 8) {
      fail("perturb_rings",
           std::to_string(perturb_rings),
           "0 <= perturb_rings <= 8");
    }
  }
  if (random_layouts > 0 || perturbed_layouts > 0) {
    if (!(random_share >= 0 && random_share <= 1)) {
      fail("random_share",
           fmt::format("{}", random_share),
           "0 <= random_share <= 1");
    }
  }
  if (random_layouts > 0) {
    const std::string markers =
        fmt::format("[{}, {}]", random_min_markers, random_max_markers);
    if (random_min_markers < 1 || random_min_markers > random_max_markers) {
      fail("random_markers", markers, "1 <= min <= max");
    }
    if (random_max_markers > max_labels) {
      fail("random_markers", markers, "max <= max_labels (the model's slots)");
    }
    if (!(random_min_spacing >= 0)) {
      fail("random_min_spacing",
           fmt::format("{}", random_min_spacing),
           "random_min_spacing >= 0");
    }
  }
}

LayoutSamplerOptions DecodeLayoutSamplerOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  LayoutSamplerOptions options;
  std::string name;
  reader.Require("name", &name);
  reader.Check("name",
               name == "builtin" || name == "mixed" || name == "random",
               "name is builtin, mixed or random");
  reader.Read("layouts", &options.layouts);
  reader.Read("max_labels", &options.max_labels);
  reader.Read("shuffle_slots", &options.shuffle_slots);
  reader.Read("random_layouts", &options.random_layouts);
  std::vector<int> markers = {options.random_min_markers,
                              options.random_max_markers};
  reader.Read("random_markers", &markers);
  reader.Check("random_markers", markers.size() == 2, "a list [min, max]");
  options.random_min_markers = markers[0];
  options.random_max_markers = markers[1];
  reader.Read("random_min_spacing", &options.random_min_spacing);
  reader.Read("random_share", &options.random_share);
  reader.Read("random_seed", &options.random_seed);
  reader.Read("perturbed_layouts", &options.perturbed_layouts);
  reader.Read("perturb_keep", &options.perturb_keep);
  reader.Read("perturb_rings", &options.perturb_rings);
  std::string draw = "vertex";
  reader.Read("perturb_draw", &draw);
  reader.Check("perturb_draw",
               draw == "vertex" || draw == "ring",
               "perturb_draw is vertex or ring");
  options.perturb_draw =
      draw == "ring" ? PerturbDraw::kRing : PerturbDraw::kVertex;
  // The name says what the sampler draws from.
  const bool listed = !options.layouts.empty();
  const bool pool = options.random_layouts > 0 || options.perturbed_layouts > 0;
  reader.Check("random_layouts",
               name != "builtin" || !pool,
               "random_layouts == 0 and perturbed_layouts == 0 for name "
               "builtin (mixed or random draw from a pool)");
  reader.Check("random_layouts",
               name == "builtin" || pool,
               name == "random" ? "random_layouts > 0 for name random"
                                : "random_layouts > 0 or perturbed_layouts > "
                                  "0 for name mixed");
  reader.Check("layouts",
               name == "random" ? !listed : listed,
               name == "random" ? "[] for name random (mixed: listed layouts "
                                  "and random ones)"
                                : "at least one layout");
  reader.Check("max_labels", options.max_labels > 0, "max_labels > 0");
  reader.Check("max_labels",
               options.max_labels <= 32767,
               "max_labels <= 32767 (int16 label ids)");
  reader.Finish();
  options.Validate();
  return options;
}

MarkerLayout MakeRandomLayout(const BodyModel& body,
                              int num_markers,
                              double min_spacing,
                              std::string_view prefix,
                              Rng* rng) {
  const Eigen::Matrix3Xd& v = body.template_vertices;
  const Eigen::Matrix3Xi& f = body.faces;
  // Area-weighted faces of the skin but the soles.
  std::vector<double> cumulative;
  std::vector<int> faces;
  double total = 0;
  for (Eigen::Index i = 0; i < f.cols(); ++i) {
    const Eigen::Vector3d n = (v.col(f(1, i)) - v.col(f(0, i)))
                                  .cross(v.col(f(2, i)) - v.col(f(0, i)));
    const double area2 = n.norm();
    if (!(area2 > 0) || n.z() < -0.7 * area2) continue;
    total += area2;
    cumulative.push_back(total);
    faces.push_back(static_cast<int>(i));
  }
  if (faces.empty()) {
    throw ShapeError(fmt::format(
        "MakeRandomLayout: body '{}' has no skin to place markers on",
        body.name));
  }
  MarkerLayout layout;
  layout.surface_model_type = body.name;
  std::vector<int> chosen;
  const int64_t max_attempts = 1000 + 200 * static_cast<int64_t>(num_markers);
  for (int64_t attempt = 0;
       attempt < max_attempts && static_cast<int>(chosen.size()) < num_markers;
       ++attempt) {
    const double u = rng->Uniform(0, total);
    const size_t j =
        std::min(static_cast<size_t>(
                     std::upper_bound(cumulative.begin(), cumulative.end(), u) -
                     cumulative.begin()),
                 faces.size() - 1);
    // A uniform point of the face; its nearest corner has the largest
    // barycentric coordinate.
    double a = rng->Uniform();
    double b = rng->Uniform();
    if (a + b > 1) {
      a = 1 - a;
      b = 1 - b;
    }
    const double c = 1 - a - b;
    const int corner = a >= b && a >= c ? 0 : (b >= c ? 1 : 2);
    const int vertex = f(corner, faces[j]);
    bool far_enough = true;
    for (const int other : chosen) {
      if (other == vertex ||
          (v.col(other) - v.col(vertex)).norm() < min_spacing) {
        far_enough = false;
        break;
      }
    }
    if (far_enough) chosen.push_back(vertex);
  }
  if (static_cast<int>(chosen.size()) < num_markers) {
    throw ConfigError(fmt::format(
        "MakeRandomLayout: placed {} of {} markers {} m apart on body '{}' in "
        "{} attempts (lower layout_sampler.random_min_spacing or "
        "random_markers)",
        chosen.size(),
        num_markers,
        min_spacing,
        body.name,
        max_attempts));
  }
  for (size_t m = 0; m < chosen.size(); ++m) {
    MarkerLayout::Marker marker;
    marker.label = fmt::format("{}_{:02d}", prefix, m);
    marker.vertex_ids = {chosen[m]};
    layout.markers.push_back(std::move(marker));
  }
  layout.Sort();
  return layout;
}

MarkerLayout MakePerturbedLayout(
    const MarkerLayout& layout,
    const std::vector<std::vector<int>>& neighbours,
    double keep,
    int rings,
    std::string_view prefix,
    Rng* rng,
    PerturbDraw draw) {
  if (layout.markers.empty()) {
    throw ConfigError("MakePerturbedLayout: the layout has no markers");
  }
  std::vector<int> kept;
  for (int m = 0; m < layout.num_markers(); ++m) {
    if (rng->Bernoulli(keep)) kept.push_back(m);
  }
  if (kept.empty()) {
    kept.push_back(
        static_cast<int>(rng->UniformInt(0, layout.num_markers() - 1)));
  }
  MarkerLayout out;
  out.surface_model_type = layout.surface_model_type;
  std::vector<int> taken;
  for (const int m : kept) {
    const MarkerLayout::Marker& marker = layout.markers[m];
    const int vertex = marker.vertex_ids.front();
    if (vertex < 0 || vertex >= static_cast<int>(neighbours.size())) {
      throw ShapeError(fmt::format(
          "MakePerturbedLayout: marker '{}' is on vertex {} of a mesh of {} "
          "vertices",
          marker.label,
          vertex,
          neighbours.size()));
    }
    const auto is_taken = [&](int v) {
      return std::find(taken.begin(), taken.end(), v) != taken.end();
    };
    std::vector<int> candidates;
    if (draw == PerturbDraw::kRing) {
      // The free vertices at exactly r rings: the r-ring less the
      // (r-1)-ring.
      const int r = static_cast<int>(rng->UniformInt(0, rings));
      candidates = {vertex};
      if (r > 0) {
        candidates = NRing(neighbours, vertex, r);
        const std::vector<int> inner = NRing(neighbours, vertex, r - 1);
        std::erase_if(candidates, [&](int v) {
          return std::binary_search(inner.begin(), inner.end(), v);
        });
      }
      std::erase_if(candidates, is_taken);
    }
    if (candidates.empty()) {  // the vertex draw, or the ring draw's fallback
      candidates = NRing(neighbours, vertex, rings);
      candidates.push_back(vertex);
      std::erase_if(candidates, is_taken);
    }
    if (candidates.empty()) continue;  // its whole ring is taken: dropped
    const int moved = candidates[static_cast<size_t>(
        rng->UniformInt(0, static_cast<int64_t>(candidates.size()) - 1))];
    taken.push_back(moved);
    MarkerLayout::Marker copy = marker;
    copy.label = fmt::format("{}_{}", prefix, marker.label);
    copy.vertex_ids = {moved};
    out.markers.push_back(std::move(copy));
  }
  out.Sort();
  return out;
}

LayoutSampler::LayoutSampler(const BodyModel& body,
                             LayoutSamplerOptions options)
    : options_(std::move(options)) {
  options_.Validate();
  const VertexDescriptors vertices = ComputeVertexDescriptors(body);
  descriptor_width_ = LabelDescriptorWidth(vertices.num_joints());
  for (const std::string& name : options_.layouts) {
    const bool is_file =
        name.size() > 5 && name.compare(name.size() - 5, 5, ".json") == 0;
    MarkerLayout layout = is_file ? LoadMarkerLayoutForBody(name, body)
                                  : MakeBuiltinLayout(body, name);
    if (layout.num_markers() > options_.max_labels) {
      throw ConfigError(fmt::format(
          "layout_sampler: layout '{}' has {} markers, more than the model's "
          "{} label slots (model max_labels)",
          name,
          layout.num_markers(),
          options_.max_labels));
    }
    AddLayout(vertices, std::move(layout));
  }
  const Rng pool(Rng(options_.random_seed).Stream("random_layouts"));
  for (int i = 0; i < options_.random_layouts; ++i) {
    Rng rng = pool.Stream(static_cast<uint64_t>(i));
    const int k = static_cast<int>(rng.UniformInt(options_.random_min_markers,
                                                  options_.random_max_markers));
    MarkerLayout layout = MakeRandomLayout(body,
                                           k,
                                           options_.random_min_spacing,
                                           fmt::format("random{:03d}", i),
                                           &rng);
    AddLayout(vertices, std::move(layout));
  }
  if (options_.perturbed_layouts > 0) {
    const std::vector<std::vector<int>> neighbours = VertexNeighbours(
        static_cast<int>(body.template_vertices.cols()), body.faces);
    const Rng perturbed(Rng(options_.random_seed).Stream("perturbed_layouts"));
    const int listed = num_listed();
    for (int i = 0; i < options_.perturbed_layouts; ++i) {
      Rng rng = perturbed.Stream(static_cast<uint64_t>(i));
      const int source = static_cast<int>(rng.UniformInt(0, listed - 1));
      MarkerLayout layout =
          MakePerturbedLayout(layouts_[source],
                              neighbours,
                              options_.perturb_keep,
                              options_.perturb_rings,
                              fmt::format("perturbed{:03d}", i),
                              &rng,
                              options_.perturb_draw);
      AddLayout(vertices, std::move(layout));
    }
  }
  const int rows = row_offsets_.back() + layouts_.back().num_markers();
  if (rows > 32767) {
    throw ConfigError(fmt::format(
        "layout_sampler: the layouts hold {} markers in all, more than the "
        "32767 int16 slot rows (fewer random_layouts or perturbed_layouts)",
        rows));
  }
}

void LayoutSampler::AddLayout(const VertexDescriptors& vertices,
                              MarkerLayout layout) {
  row_offsets_.push_back(row_offsets_.empty()
                             ? 0
                             : row_offsets_.back() +
                                   layouts_.back().num_markers());
  descriptors_.push_back(LayoutDescriptors(vertices, layout));
  layouts_.push_back(std::move(layout));
}

LayoutDraw LayoutSampler::Draw(uint64_t seed, int64_t block) const {
  Rng rng = Rng(seed).Stream("layout").Stream(static_cast<uint64_t>(block));
  LayoutDraw draw;
  const int listed = num_listed();
  const int pool = num_layouts() - listed;
  if (pool == 0) {
    // The first version's draws, kept so that its runs reproduce.
    draw.layout = static_cast<int>(rng.UniformInt(0, listed - 1));
    if (options_.cycle_layouts) draw.layout = static_cast<int>(block % listed);
  } else {
    int group = listed;  // the pool
    if (options_.cycle_layouts) {
      group = static_cast<int>(block % (listed + 1));
    } else if (listed > 0 && !rng.Bernoulli(options_.random_share)) {
      group = static_cast<int>(rng.UniformInt(0, listed - 1));
    }
    draw.layout = group < listed
                      ? group
                      : listed + static_cast<int>(rng.UniformInt(0, pool - 1));
  }
  const int k = layouts_[draw.layout].num_markers();
  draw.slot_marker.assign(options_.max_labels, -1);
  if (options_.shuffle_slots) {
    const std::vector<int> order = rng.Permutation(k);
    for (int s = 0; s < k; ++s) draw.slot_marker[s] = order[s];
  } else {
    for (int s = 0; s < k; ++s) draw.slot_marker[s] = s;
  }
  return draw;
}

std::vector<std::string> LayoutSampler::SlotLabels(
    const LayoutDraw& draw) const {
  std::vector<std::string> labels(draw.slot_marker.size());
  for (size_t s = 0; s < labels.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      labels[s] = layouts_[draw.layout].markers[draw.slot_marker[s]].label;
    }
  }
  return labels;
}

Eigen::MatrixXf LayoutSampler::SlotDescriptors(const LayoutDraw& draw) const {
  const Eigen::MatrixXf& q = descriptors_[draw.layout];
  Eigen::MatrixXf out = Eigen::MatrixXf::Zero(
      static_cast<Eigen::Index>(draw.slot_marker.size()), descriptor_width_);
  for (size_t s = 0; s < draw.slot_marker.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      out.row(static_cast<Eigen::Index>(s)) = q.row(draw.slot_marker[s]);
    }
  }
  return out;
}

std::vector<uint8_t> LayoutSampler::SlotMask(const LayoutDraw& draw) const {
  std::vector<uint8_t> mask(draw.slot_marker.size());
  for (size_t s = 0; s < mask.size(); ++s) {
    mask[s] = draw.slot_marker[s] >= 0 ? 1 : 0;
  }
  return mask;
}

SlotTable LayoutSampler::BuildSlotTable() const {
  SlotTable table;
  table.width = descriptor_width_;
  table.layouts = options_.layouts;
  // The pool is one group, named after what it holds.
  if (num_layouts() > num_listed()) {
    const bool random = options_.random_layouts > 0;
    const bool perturbed = options_.perturbed_layouts > 0;
    table.layouts.push_back(random && perturbed ? "pool"
                            : random            ? "random"
                                                : "perturbed");
  }
  for (int k = 0; k < num_layouts(); ++k) {
    const Eigen::MatrixXf& q = descriptors_[k];
    for (Eigen::Index m = 0; m < q.rows(); ++m) {
      for (Eigen::Index c = 0; c < q.cols(); ++c) {
        table.rows.push_back(q(m, c));
      }
      table.names.push_back(layouts_[k].markers[m].label);
      table.row_layout.push_back(group(k));
    }
  }
  return table;
}

std::vector<int16_t> LayoutSampler::SlotRows(const LayoutDraw& draw) const {
  std::vector<int16_t> rows(draw.slot_marker.size(), -1);
  for (size_t s = 0; s < rows.size(); ++s) {
    if (draw.slot_marker[s] >= 0) {
      rows[s] =
          static_cast<int16_t>(row_offsets_[draw.layout] + draw.slot_marker[s]);
    }
  }
  return rows;
}

int LayoutSampler::max_layout_markers() const {
  int k = 0;
  for (const MarkerLayout& layout : layouts_) {
    k = std::max(k, layout.num_markers());
  }
  return k;
}

}  // namespace soma
