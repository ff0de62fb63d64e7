#include "framework/view/view_data.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

namespace soma {
namespace {

constexpr int64_t kJsonOverheadBytes = int64_t{64} * 1024;  // meta, labels
constexpr uint16_t kUnknownConfidence = 65535;

int64_t Base64Size(int64_t bytes) { return (bytes + 2) / 3 * 4; }

/// Bytes of one label id: uint8 while L + 1 (no ground truth) fits.
int LabelBytes(const ViewFrames& frames) {
  return frames.null_id() + 1 <= 255 ? 1 : 2;
}

int TrackBytes(const ViewFrames& frames) {
  const auto [lo, hi] =
      std::minmax_element(frames.track.begin(), frames.track.end());
  if (lo == frames.track.end()) return 2;
  return *hi <= std::numeric_limits<int16_t>::max() &&
                 *lo >= std::numeric_limits<int16_t>::min()
             ? 2
             : 4;
}

/// Points of the frames t = 0, step, 2 step, ...
int64_t ShownPoints(const ViewFrames& frames, int step) {
  int64_t n = 0;
  for (int t = 0; t < frames.num_frames(); t += step) {
    n += frames.offsets[t + 1] - frames.offsets[t];
  }
  return n;
}

int ShownFrames(int take_frames, int step) {
  return (take_frames + step - 1) / step;
}

std::string FiniteOrNull(double value) {
  return std::isfinite(value) ? fmt::format("{}", value) : "null";
}

/// One entry of "arrays": {"dtype": ..., "length": ..., "base64": ...}.
template <typename T>
std::string ArrayJson(std::string_view dtype, const std::vector<T>& values) {
  return fmt::format(R"({{"dtype":"{}","length":{},"base64":"{}"}})",
                     dtype,
                     values.size(),
                     Base64Encode(values.data(), values.size() * sizeof(T)));
}

/// `values` converted to T (ids that fit T by construction).
template <typename T, typename U>
std::vector<T> Narrow(const std::vector<U>& values) {
  std::vector<T> out(values.size());
  for (size_t i = 0; i < values.size(); ++i) out[i] = static_cast<T>(values[i]);
  return out;
}

template <typename U>
std::string IdArrayJson(int bytes, const std::vector<U>& values, bool sign) {
  if (sign) {
    return bytes == 2 ? ArrayJson("int16", Narrow<int16_t>(values))
                      : ArrayJson("int32", Narrow<int32_t>(values));
  }
  return bytes == 1 ? ArrayJson("uint8", Narrow<uint8_t>(values))
                    : ArrayJson("uint16", Narrow<uint16_t>(values));
}

}  // namespace

std::string Base64Encode(const void* data, size_t size) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* bytes = static_cast<const uint8_t*>(data);
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 3 <= size; i += 3) {
    const uint32_t v = (uint32_t{bytes[i]} << 16) |
                       (uint32_t{bytes[i + 1]} << 8) | bytes[i + 2];
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(kAlphabet[(v >> 6) & 63]);
    out.push_back(kAlphabet[v & 63]);
  }
  if (i < size) {
    uint32_t v = uint32_t{bytes[i]} << 16;
    if (i + 1 < size) v |= uint32_t{bytes[i + 1]} << 8;
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(i + 1 < size ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

std::string JsonString(std::string_view text) {
  std::string out = "\"";
  for (const char c : text) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      case '<':
      case '>':
      case '&':
        out += fmt::format("\\u{:04x}", static_cast<int>(c));
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          out += fmt::format("\\u{:04x}", static_cast<int>(c));
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

PointStatus ClassifyPoint(int label, int truth, int num_labels) {
  if (truth < 0 || truth > num_labels) return PointStatus::kNoTruth;
  const bool label_null = label >= num_labels;
  if (label == truth || (label_null && truth == num_labels)) {
    return PointStatus::kCorrect;
  }
  if (truth == num_labels) return PointStatus::kGhostAsMarker;
  if (label_null) return PointStatus::kMissed;
  return PointStatus::kWrong;
}

void ViewFrames::AddPoint(const float position[3],
                          int label_id,
                          int truth_id,
                          float point_confidence,
                          int track_id) {
  positions.insert(positions.end(), position, position + 3);
  label.push_back(label_id);
  if (with_truth) truth.push_back(truth_id);
  if (with_confidence) confidence.push_back(point_confidence);
  track.push_back(track_id);
}

void ViewFrames::Validate() const {
  const int64_t P = num_points();
  const int L = null_id();
  if (offsets.empty() || offsets.front() != 0 ||
      !std::is_sorted(offsets.begin(), offsets.end())) {
    throw ShapeError("view data: frame offsets must start at 0 and grow");
  }
  auto check = [&](std::string_view name, size_t size, int64_t expected) {
    if (static_cast<int64_t>(size) != expected) {
      throw ShapeError(fmt::format(
          "view data: {} has {} entries, expected {}", name, size, expected));
    }
  };
  check("positions", positions.size(), 3 * P);
  check("label", label.size(), P);
  check("track", track.size(), P);
  if (has_truth()) check("truth", truth.size(), P);
  if (has_confidence()) check("confidence", confidence.size(), P);
  for (int64_t i = 0; i < P; ++i) {
    if (label[i] < 0 || label[i] > L ||
        (has_truth() && (truth[i] < 0 || truth[i] > L + 1))) {
      throw ShapeError(fmt::format(
          "view data: point {} has label id {} / true id {}, expected 0..{}",
          i,
          label[i],
          has_truth() ? truth[i] : 0,
          L));
    }
  }
  if (mesh_frames.size() != mesh_vertices.size()) {
    throw ShapeError(fmt::format("view data: {} mesh frames but {} meshes",
                                 mesh_frames.size(),
                                 mesh_vertices.size()));
  }
  if (has_mesh()) {
    const size_t coords = mesh_vertices.front().size();
    const int V = static_cast<int>(coords / 3);
    if (coords == 0 || coords % 3 != 0 || mesh_faces.empty() ||
        mesh_faces.size() % 3 != 0) {
      throw ShapeError(
          fmt::format("view data: meshes of {} coordinates and {} face indices",
                      coords,
                      mesh_faces.size()));
    }
    for (size_t m = 0; m < mesh_frames.size(); ++m) {
      if (mesh_vertices[m].size() != coords ||
          mesh_frames[m] < (m == 0 ? 0 : mesh_frames[m - 1] + 1) ||
          mesh_frames[m] >= num_frames()) {
        throw ShapeError(fmt::format(
            "view data: mesh {} (take frame {}, {} coordinates) out of order "
            "or size",
            m,
            mesh_frames[m],
            mesh_vertices[m].size()));
      }
    }
    for (const int v : mesh_faces) {
      if (v < 0 || v >= V) {
        throw ShapeError(fmt::format(
            "view data: mesh face vertex {} outside 0..{}", v, V - 1));
      }
    }
  }
  for (const auto& [a, b] : sticks) {
    if (a < 0 || a >= L || b < 0 || b >= L) {
      throw ShapeError(
          fmt::format("view data: stick {}-{} outside 0..{}", a, b, L - 1));
    }
  }
}

void ViewPageOptions::Validate() const {
  if (max_page_bytes <= 0 || template_bytes < 0) {
    throw ConfigError(fmt::format(
        "Invalid configuration. max_page_bytes = {}. Violated constraint: a "
        "positive page size",
        max_page_bytes));
  }
}

int64_t EstimateDataBytes(const ViewFrames& frames, int step) {
  const int64_t F = ShownFrames(frames.num_frames(), step);
  const int64_t P = ShownPoints(frames, step);
  const int label_bytes = LabelBytes(frames);
  int64_t bytes = Base64Size(4 * F) + Base64Size(4 * (F + 1)) +
                  Base64Size(12 * P) + Base64Size(label_bytes * P) +
                  Base64Size(int64_t{TrackBytes(frames)} * P);
  if (frames.has_truth()) {
    bytes += Base64Size(label_bytes * P) + Base64Size(P) + Base64Size(4 * F);
  }
  if (frames.has_confidence()) {
    bytes += Base64Size(2 * P) + Base64Size(4 * F);
  }
  if (frames.has_mesh()) {
    bytes += EstimateMeshBytes(
        static_cast<int>(frames.mesh_vertices.front().size() / 3),
        static_cast<int>(frames.mesh_faces.size() / 3),
        static_cast<int>(frames.mesh_frames.size()));
  }
  return bytes;
}

int64_t EstimateMeshBytes(int num_vertices, int num_faces, int num_meshes) {
  const int index_bytes = num_vertices <= 65535 ? 2 : 4;
  return Base64Size(int64_t{index_bytes} * 3 * num_faces) +
         Base64Size(4 * int64_t{num_meshes}) +
         Base64Size(int64_t{num_meshes} * num_vertices * 3 * 2);
}

int ChooseMeshStep(int num_vertices,
                   int num_faces,
                   int num_candidates,
                   int64_t budget_bytes) {
  for (int k = 1; k <= std::max(num_candidates, 1); ++k) {
    const int meshes = (num_candidates + k - 1) / k;
    if (EstimateMeshBytes(num_vertices, num_faces, meshes) <= budget_bytes) {
      return k;
    }
  }
  return 0;
}

int ChooseFrameStep(const ViewFrames& frames, const ViewPageOptions& options) {
  options.Validate();
  const int64_t budget = options.max_page_bytes - options.template_bytes -
                         kJsonOverheadBytes -
                         static_cast<int64_t>(frames.labels.size()) * 32;
  // The size need not fall monotonically with the step (frames differ in
  // their point counts), so try every step in turn: each try is one pass
  // over the frame offsets.
  const int T = std::max(frames.num_frames(), 1);
  for (int step = 1; step <= T; ++step) {
    if (EstimateDataBytes(frames, step) <= budget) return step;
  }
  throw ConfigError(fmt::format(
      "Invalid configuration. task.max_page_mb = {:.3f}. Violated "
      "constraint: room for one frame of {} beside the {} byte template "
      "(one frame needs {} bytes)",
      options.max_page_bytes / 1e6,
      frames.source,
      options.template_bytes,
      EstimateDataBytes(frames, T) + kJsonOverheadBytes));
}

std::string PackViewData(const ViewFrames& frames,
                         const ViewPageOptions& options,
                         ViewDataSummary* summary) {
  frames.Validate();
  const int step = ChooseFrameStep(frames, options);
  const int T = frames.num_frames();
  const int L = frames.null_id();

  std::vector<uint32_t> frame_index, offset{0};
  std::vector<float> position, accuracy, confidence_mean;
  std::vector<int> label, truth, track;
  std::vector<uint8_t> status;
  std::vector<uint16_t> confidence;
  ViewDataSummary local;
  for (int t = 0; t < T; t += step) {
    frame_index.push_back(static_cast<uint32_t>(t));
    int64_t pairs = 0, correct = 0, confident = 0;
    double confidence_sum = 0.0;
    for (int64_t i = frames.offsets[t]; i < frames.offsets[t + 1]; ++i) {
      position.insert(position.end(),
                      frames.positions.begin() + 3 * i,
                      frames.positions.begin() + 3 * i + 3);
      label.push_back(frames.label[i]);
      track.push_back(frames.track[i]);
      if (frames.has_truth()) {
        truth.push_back(frames.truth[i]);
        const PointStatus s =
            ClassifyPoint(frames.label[i], frames.truth[i], L);
        status.push_back(static_cast<uint8_t>(s));
        ++local.status_counts[static_cast<int>(s)];
        if (s != PointStatus::kNoTruth) {
          ++pairs;
          correct += s == PointStatus::kCorrect;
        }
      }
      if (frames.has_confidence()) {
        const float c = frames.confidence[i];
        if (std::isnan(c)) {
          confidence.push_back(kUnknownConfidence);
        } else {
          const float clamped = std::clamp(c, 0.0f, 1.0f);
          confidence.push_back(
              static_cast<uint16_t>(std::lround(clamped * 65534.0f)));
          confidence_sum += clamped;
          ++confident;
        }
      }
    }
    offset.push_back(static_cast<uint32_t>(label.size()));
    if (frames.has_truth()) {
      accuracy.push_back(pairs > 0 ? static_cast<float>(correct) / pairs
                                   : std::numeric_limits<float>::quiet_NaN());
    }
    if (frames.has_confidence()) {
      confidence_mean.push_back(
          confident > 0 ? static_cast<float>(confidence_sum / confident)
                        : std::numeric_limits<float>::quiet_NaN());
    }
  }

  local.take_frames = T;
  local.shown_frames = static_cast<int>(frame_index.size());
  local.frame_step = step;
  local.shown_points = static_cast<int64_t>(label.size());
  if (step > 1) {
    local.note = fmt::format(
        "Subsampled: 1 frame in {} is shown ({} of {} frames); all frames "
        "would make the page larger than {:.0f} MB.",
        step,
        local.shown_frames,
        T,
        options.max_page_bytes / 1e6);
  }

  const int label_bytes = L + 1 <= 255 ? 1 : 2;
  std::string arrays;
  arrays += R"("frame":)" + ArrayJson("uint32", frame_index);
  arrays += R"(,"offset":)" + ArrayJson("uint32", offset);
  arrays += R"(,"position":)" + ArrayJson("float32", position);
  arrays += R"(,"label":)" + IdArrayJson(label_bytes, label, false);
  arrays += R"(,"track":)" + IdArrayJson(TrackBytes(frames), track, true);
  if (frames.has_truth()) {
    arrays += R"(,"truth":)" + IdArrayJson(label_bytes, truth, false);
    arrays += R"(,"status":)" + ArrayJson("uint8", status);
    arrays += R"(,"accuracy":)" + ArrayJson("float32", accuracy);
  }
  if (frames.has_confidence()) {
    arrays += R"(,"confidence":)" + ArrayJson("uint16", confidence);
    arrays += R"(,"confidence_mean":)" + ArrayJson("float32", confidence_mean);
  }
  std::string mesh_unit = "mm";
  if (frames.has_mesh()) {
    const size_t V3 = frames.mesh_vertices.front().size();
    arrays += R"(,"mesh_faces":)" +
              (V3 / 3 <= 65535
                   ? ArrayJson("uint16", Narrow<uint16_t>(frames.mesh_faces))
                   : ArrayJson("uint32", Narrow<uint32_t>(frames.mesh_faces)));
    arrays += R"(,"mesh_frame":)" +
              ArrayJson("uint32", Narrow<uint32_t>(frames.mesh_frames));
    float extent = 0.0f;
    for (const auto& mesh : frames.mesh_vertices) {
      for (const float v : mesh) extent = std::max(extent, std::abs(v));
    }
    if (extent * 1000.0f < 32767.0f) {
      std::vector<int16_t> mm;
      mm.reserve(V3 * frames.mesh_vertices.size());
      for (const auto& mesh : frames.mesh_vertices) {
        for (const float v : mesh) {
          mm.push_back(static_cast<int16_t>(std::lround(v * 1000.0f)));
        }
      }
      arrays += R"(,"mesh_vertices":)" + ArrayJson("int16", mm);
    } else {
      mesh_unit = "m";
      std::vector<float> m;
      for (const auto& mesh : frames.mesh_vertices) {
        m.insert(m.end(), mesh.begin(), mesh.end());
      }
      arrays += R"(,"mesh_vertices":)" + ArrayJson("float32", m);
    }
  }

  std::string labels_json, sticks_json;
  for (const std::string& name : frames.labels) {
    if (!labels_json.empty()) labels_json += ',';
    labels_json += JsonString(name);
  }
  for (const auto& [a, b] : frames.sticks) {
    if (!sticks_json.empty()) sticks_json += ',';
    sticks_json += fmt::format("[{},{}]", a, b);
  }
  std::string json = fmt::format(
      R"({{"format":"soma-view","format_version":1,"title":{},"source":{},)"
      R"("truth_source":{},"confidence_source":{},"track_source":{},)"
      R"("frame_rate":{},"first_frame":{},"take_frames":{},"frame_step":{},)"
      R"("num_frames":{},"num_points":{},"note":{},"has_truth":{},)"
      R"("has_confidence":{},"has_mesh":{},"mesh_source":{},"mesh_step":{},)"
      R"("mesh_unit":"{}","labels":[{}],"sticks":[{}],"arrays":{{{}}}}})",
      JsonString(frames.title),
      JsonString(frames.source),
      JsonString(frames.truth_source),
      JsonString(frames.confidence_source),
      JsonString(frames.track_source),
      FiniteOrNull(frames.frame_rate),
      frames.first_frame,
      T,
      step,
      local.shown_frames,
      local.shown_points,
      JsonString(local.note),
      frames.has_truth(),
      frames.has_confidence(),
      frames.has_mesh(),
      JsonString(frames.mesh_source),
      frames.mesh_step,
      mesh_unit,
      labels_json,
      sticks_json,
      arrays);
  local.data_bytes = static_cast<int64_t>(json.size());
  if (summary != nullptr) *summary = local;
  return json;
}

std::string FillViewTemplate(std::string_view html,
                             std::string_view json,
                             std::string_view template_name) {
  const size_t at = html.find(kViewDataPlaceholder);
  if (at == std::string_view::npos ||
      html.find(kViewDataPlaceholder, at + 1) != std::string_view::npos) {
    throw IoError(fmt::format(
        "{}: a soma view template holds the placeholder {} exactly once ({}); "
        "rebuild it with viewer/build.mjs",
        template_name,
        kViewDataPlaceholder,
        at == std::string_view::npos ? "not found" : "found twice"));
  }
  std::string out;
  out.reserve(html.size() + json.size());
  out.append(html.substr(0, at));
  out.append(json);
  out.append(html.substr(at + kViewDataPlaceholder.size()));
  return out;
}

}  // namespace soma
