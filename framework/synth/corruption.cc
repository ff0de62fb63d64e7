#include "framework/synth/corruption.h"

#include "framework/body/marker_layout.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"
#include "framework/core/provenance.h"
#include "framework/core/random.h"
#include "framework/io/c3d.h"
#include "framework/synth/ghosts.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <regex>

namespace soma {

std::string CorruptionSettingName(const CorruptionSetting& setting) {
  return fmt::format("{}_{:02d}_G_{:02d}_BT_{:02d}",
                     setting.exact_occlusions ? "OCE" : "OC",
                     setting.occlusions,
                     setting.ghosts,
                     setting.broken_trajectories);
}

CorruptionSetting ParseCorruptionSettingName(const std::string& name) {
  static const std::regex pattern(R"((OCE?)_(\d+)_G_(\d+)_BT_(\d+))");
  std::smatch match;
  if (!std::regex_match(name, match, pattern) || match[2].length() > 6 ||
      match[3].length() > 6 || match[4].length() > 6) {
    throw ConfigError(fmt::format(
        "Invalid corruption setting name '{}': expected OC_xx_G_xx_BT_xx or "
        "OCE_xx_G_xx_BT_xx (e.g. OC_05_G_03_BT_00)",
        name));
  }
  CorruptionSetting setting;
  setting.exact_occlusions = match[1] == "OCE";
  setting.occlusions = std::stoi(match[2]);
  setting.ghosts = std::stoi(match[3]);
  setting.broken_trajectories = std::stoi(match[4]);
  return setting;
}

LabeledSequence ReadLabeledC3d(const std::filesystem::path& path,
                               const std::vector<std::string>& layout_labels) {
  const C3dData c3d = ReadC3d(path);
  std::map<std::string, int> label_id;
  for (size_t i = 0; i < layout_labels.size(); ++i) {
    label_id.emplace(layout_labels[i], static_cast<int>(i));
  }
  // Layout id -> first file point with that label.
  std::map<int, int> point_of_label;
  int matched = 0;
  for (int p = 0; p < c3d.num_points; ++p) {
    auto it = label_id.find(CanonicalMarkerLabel(c3d.labels[p]));
    if (it == label_id.end()) continue;
    ++matched;
    point_of_label.emplace(it->second, p);
  }
  if (point_of_label.empty()) {
    throw IoError(fmt::format(
        "{}: none of its {} point labels is in the layout ({} labels)",
        path.string(),
        c3d.num_points,
        layout_labels.size()));
  }
  if (static_cast<double>(matched) / point_of_label.size() > 1.5) {
    throw IoError(fmt::format(
        "{}: seems to hold several subjects ({} points for {} distinct "
        "layout labels); the protocol takes single-subject takes",
        path.string(),
        matched,
        point_of_label.size()));
  }
  LabeledSequence sequence;
  sequence.name = path.stem().string();
  sequence.frame_rate = c3d.frame_rate;
  sequence.label_names = layout_labels;
  const int num_columns = static_cast<int>(point_of_label.size());
  const int16_t null_label = static_cast<int16_t>(layout_labels.size());
  sequence.frames.Resize(c3d.num_frames, num_columns);
  const float to_metres = static_cast<float>(c3d.MetresPerUnit());
  int column = 0;
  for (const auto& [id, p] : point_of_label) {
    sequence.column_names.push_back(layout_labels[id]);
    for (int t = 0; t < c3d.num_frames; ++t) {
      float* xyz = sequence.frames.frame_points(t) + 3 * column;
      int16_t& label = sequence.frames.frame_labels(t)[column];
      if (c3d.valid(t, p)) {
        const Eigen::Vector3f point = c3d.Point(t, p) * to_metres;
        xyz[0] = point.x();
        xyz[1] = point.y();
        xyz[2] = point.z();
      } else {
        xyz[0] = xyz[1] = xyz[2] = 0.0f;
      }
      const bool zero = xyz[0] == 0.0f && xyz[1] == 0.0f && xyz[2] == 0.0f;
      label = zero ? null_label : static_cast<int16_t>(id);
    }
    ++column;
  }
  return sequence;
}

std::string CorruptionSkipReason(const LabeledSequence& sequence,
                                 const CorruptionSetting& setting) {
  const std::string name = CorruptionSettingName(setting);
  const int64_t frames = sequence.num_frames();
  if (frames < 3 * int64_t{setting.broken_trajectories} ||
      (setting.broken_trajectories > 0 && frames < 5)) {
    return fmt::format(
        "{}: {} frames < 3 x BT = {} frames; skipped for {}",
        sequence.name,
        frames,
        std::max<int64_t>(3 * int64_t{setting.broken_trajectories}, 5),
        name);
  }
  const int max_occluded =
      setting.exact_occlusions ? setting.occlusions : setting.occlusions - 1;
  if (max_occluded > sequence.num_columns()) {
    return fmt::format(
        "{}: {} occlusions requested but the take has {} "
        "markers; skipped for {}",
        sequence.name,
        max_occluded,
        sequence.num_columns(),
        name);
  }
  return "";
}

namespace {

/// One column (tracklet) over all frames.
struct Column {
  std::vector<float> xyz;       // T * 3
  std::vector<int16_t> labels;  // T
};

bool IsZero(const float* xyz) {
  return xyz[0] == 0.0f && xyz[1] == 0.0f && xyz[2] == 0.0f;
}

}  // namespace

LabeledSequence CorruptSequence(const LabeledSequence& clean,
                                const CorruptionSetting& setting,
                                uint64_t seed,
                                CorruptionSummary* summary) {
  const std::string reason = CorruptionSkipReason(clean, setting);
  if (!reason.empty()) throw ShapeError(reason);
  if (setting.occlusions < 0 || setting.ghosts < 0 ||
      setting.broken_trajectories < 0) {
    throw ConfigError(
        fmt::format("Invalid corruption setting {}: counts must "
                    "be >= 0",
                    CorruptionSettingName(setting)));
  }
  const std::string setting_name = CorruptionSettingName(setting);
  const Rng rng =
      Rng(seed).Stream("synth/corruption/" + setting_name + "/" + clean.name);
  const int64_t num_frames = clean.num_frames();
  const int num_real = clean.num_columns();
  const int16_t null_label = static_cast<int16_t>(clean.null_label());
  CorruptionSummary stats;

  // Column-major copy of the clean data.
  std::vector<Column> columns(num_real);
  int64_t missing = 0;
  for (int k = 0; k < num_real; ++k) {
    columns[k].xyz.resize(num_frames * 3);
    columns[k].labels.resize(num_frames);
    for (int64_t t = 0; t < num_frames; ++t) {
      const float* xyz = clean.frames.frame_points(t) + 3 * k;
      std::copy_n(xyz, 3, columns[k].xyz.data() + 3 * t);
      columns[k].labels[t] = clean.frames.frame_labels(t)[k];
      missing += IsZero(xyz);
    }
  }
  const double real_points = static_cast<double>(num_frames) * num_real;
  stats.missing_before = real_points > 0 ? missing / real_points : 0.0;

  // 1. Occlusions.
  if (setting.occlusions > 0) {
    Rng occlusion = rng.Stream("occlusion");
    for (int64_t t = 0; t < num_frames; ++t) {
      const int k = setting.exact_occlusions
                        ? setting.occlusions
                        : static_cast<int>(
                              occlusion.UniformInt(0, setting.occlusions - 1));
      for (int c : occlusion.SampleWithoutReplacement(num_real, k)) {
        std::fill_n(columns[c].xyz.data() + 3 * t, 3, 0.0f);
      }
    }
  }
  missing = 0;
  for (const Column& column : columns) {
    for (int64_t t = 0; t < num_frames; ++t) {
      missing += IsZero(column.xyz.data() + 3 * t);
    }
  }
  stats.missing_after = real_points > 0 ? missing / real_points : 0.0;

  // 2. Ghost points around the per-frame median/std of all columns (zeros
  // included), up-to rejection: the ghosts module's sampling (ghosts.h) with
  // exactly G spherical Gaussian ghosts per frame.
  if (setting.ghosts > 0) {
    Rng ghosts = rng.Stream("ghosts");
    const int g = setting.ghosts;
    GhostOptions options;
    options.distribution = GhostDistribution::kSphericalGaussian;
    options.max_count = g;
    options.exact = true;
    options.up_to = true;
    std::vector<Column> ghost_columns(g);
    for (Column& column : ghost_columns) {
      column.xyz.assign(num_frames * 3, 0.0f);
      column.labels.assign(num_frames, null_label);
    }
    std::vector<float> values(num_real);
    std::vector<float> xyz;
    std::vector<char> dropped;
    int64_t kept = 0;
    for (int64_t t = 0; t < num_frames; ++t) {
      GhostCentre centre;
      for (int axis = 0; axis < 3; ++axis) {
        for (int k = 0; k < num_real; ++k) {
          values[k] = columns[k].xyz[3 * t + axis];
        }
        LowerMedianAndStd(&values, &centre.median[axis], &centre.sigma[axis]);
      }
      DrawGhosts(options, g, centre, ghosts, &xyz, &dropped);
      for (int slot = 0; slot < g; ++slot) {
        if (dropped[slot]) continue;
        std::copy_n(
            xyz.data() + 3 * slot, 3, ghost_columns[slot].xyz.data() + 3 * t);
      }
      for (const Column& column : ghost_columns) {
        kept += !IsZero(column.xyz.data() + 3 * t);
      }
    }
    stats.ghosts_per_frame =
        num_frames > 0 ? static_cast<double>(kept) / num_frames : 0.0;
    for (Column& column : ghost_columns) columns.push_back(std::move(column));
  }

  // 3. Zero points are null; one permutation of the columns for all frames.
  for (Column& column : columns) {
    for (int64_t t = 0; t < num_frames; ++t) {
      if (IsZero(column.xyz.data() + 3 * t)) column.labels[t] = null_label;
    }
  }
  {
    Rng permutation = rng.Stream("permutation");
    const std::vector<int> order =
        permutation.Permutation(static_cast<int>(columns.size()));
    std::vector<Column> permuted;
    permuted.reserve(columns.size());
    for (int index : order) permuted.push_back(std::move(columns[index]));
    columns = std::move(permuted);
  }

  // 4. Broken trajectories.
  if (setting.broken_trajectories > 0) {
    Rng cuts = rng.Stream("broken_trajectories");
    // Cut times: distinct, from [2, T-2].
    const int64_t candidates = num_frames - 3;
    const int count = static_cast<int>(
        std::min<int64_t>(setting.broken_trajectories, candidates));
    std::vector<int> times =
        cuts.SampleWithoutReplacement(static_cast<int>(candidates), count);
    std::sort(times.begin(), times.end());
    std::vector<int> pool(columns.size());
    for (size_t i = 0; i < pool.size(); ++i) pool[i] = static_cast<int>(i);
    for (int offset : times) {
      const int64_t t = offset + 2;
      int column = -1;
      while (!pool.empty()) {
        const size_t i = static_cast<size_t>(
            cuts.UniformInt(0, static_cast<int64_t>(pool.size()) - 1));
        const int candidate = pool[i];
        pool.erase(pool.begin() + static_cast<std::ptrdiff_t>(i));
        if (columns[candidate].labels[t] != null_label) {
          column = candidate;
          break;
        }
      }
      if (column < 0) {
        SOMA_LOG(WARNING,
                 "{} {}: no labelled column left to cut at frame {}; {} of "
                 "{} cuts made",
                 clean.name,
                 setting_name,
                 t,
                 stats.cuts,
                 count);
        break;
      }
      Column piece;
      piece.xyz.assign(num_frames * 3, 0.0f);
      piece.labels.assign(num_frames, null_label);
      Column& source = columns[column];
      std::copy(source.xyz.begin() + 3 * t,
                source.xyz.end(),
                piece.xyz.begin() + 3 * t);
      std::copy(source.labels.begin() + t,
                source.labels.end(),
                piece.labels.begin() + t);
      std::fill(source.xyz.begin() + 3 * t, source.xyz.end(), 0.0f);
      std::fill(source.labels.begin() + t, source.labels.end(), null_label);
      columns.push_back(std::move(piece));
      pool.push_back(static_cast<int>(columns.size()) - 1);
      ++stats.cuts;
    }
  }

  // 5. Frame-major output with anonymised column names.
  LabeledSequence out;
  out.name = clean.name;
  out.frame_rate = clean.frame_rate;
  out.label_names = clean.label_names;
  const int num_columns = static_cast<int>(columns.size());
  for (int k = 0; k < num_columns; ++k) {
    out.column_names.push_back(fmt::format("*{:03d}", k));
  }
  out.frames.Resize(num_frames, num_columns);
  for (int k = 0; k < num_columns; ++k) {
    for (int64_t t = 0; t < num_frames; ++t) {
      std::copy_n(
          columns[k].xyz.data() + 3 * t, 3, out.frames.frame_points(t) + 3 * k);
      out.frames.frame_labels(t)[k] = columns[k].labels[t];
    }
  }
  if (summary != nullptr) *summary = stats;
  return out;
}

void WriteCorruptedSequence(const LabeledSequence& sequence,
                            const std::filesystem::path& stem,
                            const std::string& setting_name,
                            uint64_t seed) {
  const int64_t num_frames = sequence.num_frames();
  const int num_columns = sequence.num_columns();
  if (static_cast<int>(sequence.column_names.size()) != num_columns) {
    throw ShapeError(fmt::format("{}: {} column names for {} columns",
                                 stem.string(),
                                 sequence.column_names.size(),
                                 num_columns));
  }
  C3dData c3d;
  c3d.source = stem.string() + ".c3d";
  c3d.frame_rate = sequence.frame_rate;
  c3d.first_frame = 1;
  c3d.num_frames = static_cast<int>(num_frames);
  c3d.num_points = num_columns;
  c3d.point_scale = -1.0f;
  c3d.labels = sequence.column_names;
  c3d.num_file_labels = num_columns;
  c3d.units = "mm";
  c3d.points.setZero(num_frames, 3 * int64_t{num_columns});
  c3d.residuals.setZero(num_frames, num_columns);
  c3d.valid.setConstant(num_frames, num_columns, true);
  for (int64_t t = 0; t < num_frames; ++t) {
    const float* xyz = sequence.frames.frame_points(t);
    for (int k = 0; k < num_columns; ++k) {
      if (IsZero(xyz + 3 * k)) {
        c3d.residuals(t, k) = -1.0f;
        c3d.valid(t, k) = false;
        continue;
      }
      for (int axis = 0; axis < 3; ++axis) {
        c3d.points(t, 3 * k + axis) = xyz[3 * k + axis] * 1000.0f;
      }
    }
  }
  WriteC3d(stem.string() + ".c3d", c3d);

  DatasetInfo info;
  info.labels = sequence.label_names;
  info.num_points = num_columns;
  info.frame_rate = sequence.frame_rate;
  info.seed = seed;
  info.code_version = GetBuildInfo().version;
  std::string columns;
  for (const std::string& name : sequence.column_names) {
    columns += (columns.empty() ? "" : ",") + name;
  }
  info.attributes = {{"source", sequence.name},
                     {"setting", setting_name},
                     {"columns", columns},
                     {"content", "corrupted real mocap, ground-truth labels"}};
  DatasetWriter writer(stem.string() + ".h5", info);
  writer.Append(sequence.frames);
  writer.Close();
}

}  // namespace soma
