// `soma realism`: how human is the synthetic world? Compares rigid
// inter-marker distances within body segments (head, pelvis, thigh, shank,
// upper arm, forearm) of the 41-marker layout on the body at mean shape with
// the medians over frames of real captures (HDM05 and CMU takes). Writes
// realism.md / realism.csv and reports the worst segment's relative error.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/io/c3d.h"
#include "framework/tasks/components.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

namespace soma {
namespace {

struct MarkerPair {
  const char* segment;
  const char* a;
  const char* b;
};

/// Pairs of markers on one rigid segment (CMU/HDM05 41-marker names).
constexpr MarkerPair kPairs[] = {
    {"head", "LFHD", "RFHD"},      {"head", "LBHD", "RBHD"},
    {"head", "LFHD", "LBHD"},      {"head", "RFHD", "RBHD"},
    {"pelvis", "LFWT", "RFWT"},    {"pelvis", "LBWT", "RBWT"},
    {"pelvis", "LFWT", "LBWT"},    {"pelvis", "RFWT", "RBWT"},
    {"thigh", "LTHI", "LKNE"},     {"thigh", "RTHI", "RKNE"},
    {"shank", "LKNE", "LANK"},     {"shank", "RKNE", "RANK"},
    {"shank", "LSHN", "LANK"},     {"shank", "RSHN", "RANK"},
    {"upper_arm", "LSHO", "LELB"}, {"upper_arm", "RSHO", "RELB"},
    {"upper_arm", "LUPA", "LELB"}, {"upper_arm", "RUPA", "RELB"},
    {"forearm", "LELB", "LWRA"},   {"forearm", "RELB", "RWRA"},
    {"forearm", "LWRA", "LWRB"},   {"forearm", "RWRA", "RWRB"},
    {"forearm", "LFRM", "LWRB"},   {"forearm", "RFRM", "RWRB"},
};

struct RealismOptions {
  std::vector<std::string> files;
  double tolerance = 0.15;  // max relative error of a segment's mean distance
  int frame_stride = 4;     // frames sampled from each take
};

/// Median distance of every pair over the valid frames of a take (metres);
/// NaN where a label is missing.
std::vector<double> RealDistances(const std::string& path, int stride) {
  const C3dData c3d = ReadC3d(path);
  std::map<std::string, int> index;
  for (int p = 0; p < c3d.num_points; ++p) {
    index.emplace(std::string(StripSubjectPrefix(c3d.labels[p])), p);
  }
  const double to_metres = c3d.MetresPerUnit();
  std::vector<double> medians;
  for (const MarkerPair& pair : kPairs) {
    auto a = index.find(pair.a), b = index.find(pair.b);
    if (a == index.end() || b == index.end()) {
      medians.push_back(std::nan(""));
      continue;
    }
    std::vector<double> d;
    for (int t = 0; t < c3d.num_frames; t += std::max(1, stride)) {
      if (!c3d.valid(t, a->second) || !c3d.valid(t, b->second)) continue;
      d.push_back((c3d.Point(t, a->second) - c3d.Point(t, b->second))
                      .cast<double>()
                      .norm() *
                  to_metres);
    }
    if (d.empty()) {
      medians.push_back(std::nan(""));
      continue;
    }
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    medians.push_back(d[d.size() / 2]);
  }
  return medians;
}

class RealismTask : public Task {
 public:
  explicit RealismTask(RealismOptions options) : options_(std::move(options)) {}

  void Run(const ConfigNode& cfg, RunContext& ctx) override {
    BuildContext build(ctx.seed, ctx.output_dir.string());
    const BodyModel body = BuildBody(cfg, build);
    const MarkerLayout layout = BuildLayout(cfg, body, build);
    const Eigen::Matrix3Xd vertices = body.template_vertices;
    const Eigen::Matrix3Xd markers =
        MarkerPositions(layout, vertices, VertexNormals(vertices, body.faces));
    const size_t num_pairs = std::size(kPairs);
    std::vector<double> synthetic(num_pairs);
    for (size_t i = 0; i < num_pairs; ++i) {
      const int a = layout.FindLabel(kPairs[i].a),
                b = layout.FindLabel(kPairs[i].b);
      if (a < 0 || b < 0) {
        throw ConfigError(
            fmt::format("Invalid configuration. The realism check needs the "
                        "CMU/HDM05 41-marker labels; "
                        "layout has no '{}' (use layout=cmu41)",
                        a < 0 ? kPairs[i].a : kPairs[i].b));
      }
      synthetic[i] = (markers.col(a) - markers.col(b)).norm();
    }
    std::vector<std::vector<double>> real;
    for (const std::string& file : options_.files) {
      real.push_back(RealDistances(file, options_.frame_stride));
      SOMA_LOG(INFO, "realism: read {}", file);
    }

    // Per segment: mean over its pairs of the body distance and of the real
    // distance (mean over takes of the per-take medians).
    std::map<std::string, std::pair<double, double>>
        segments;  // body sum, real sum
    std::map<std::string, int> counts;
    std::vector<std::string> order;
    std::ostringstream csv;
    csv << "segment,pair,body_m";
    for (const std::string& file : options_.files) {
      csv << ",real_median_m_" << std::filesystem::path(file).stem().string();
    }
    csv << ",real_mean_m,relative_error\n";
    for (size_t i = 0; i < num_pairs; ++i) {
      double sum = 0;
      int n = 0;
      for (const auto& r : real) {
        if (std::isfinite(r[i])) {
          sum += r[i];
          ++n;
        }
      }
      const double real_mean = n > 0 ? sum / n : std::nan("");
      csv << fmt::format("{},{}-{},{:.4f}",
                         kPairs[i].segment,
                         kPairs[i].a,
                         kPairs[i].b,
                         synthetic[i]);
      for (const auto& r : real) csv << fmt::format(",{:.4f}", r[i]);
      csv << fmt::format(
          ",{:.4f},{:.4f}\n", real_mean, synthetic[i] / real_mean - 1);
      if (!std::isfinite(real_mean)) continue;
      if (!segments.count(kPairs[i].segment))
        order.push_back(kPairs[i].segment);
      segments[kPairs[i].segment].first += synthetic[i];
      segments[kPairs[i].segment].second += real_mean;
      ++counts[kPairs[i].segment];
    }
    std::ostringstream md;
    md << fmt::format(
        "# Realism check: {} body, layout {} markers, mean shape\n\n"
        "Segment distance = mean over the segment's marker pairs; real = mean "
        "over takes of "
        "the median over frames (every {}th frame). Tolerance "
        "{:.0f}%.\n\nTakes: {}\n\n"
        "| segment | pairs | body (m) | real (m) | relative error | within "
        "tolerance |\n"
        "|---|---|---|---|---|---|\n",
        body.name,
        layout.num_markers(),
        options_.frame_stride,
        100 * options_.tolerance,
        fmt::join(options_.files, ", "));
    double worst = 0;
    bool all_pass = true;
    for (const std::string& segment : order) {
      const auto [body_sum, real_sum] = segments[segment];
      const double error = body_sum / real_sum - 1;
      const bool pass = std::abs(error) <= options_.tolerance;
      all_pass = all_pass && pass;
      worst = std::max(worst, std::abs(error));
      md << fmt::format("| {} | {} | {:.4f} | {:.4f} | {:+.1f}% | {} |\n",
                        segment,
                        counts[segment],
                        body_sum / counts[segment],
                        real_sum / counts[segment],
                        100 * error,
                        pass ? "yes" : "NO");
      ctx.ReportMetric("error_" + segment, error);
    }
    md << fmt::format("\nWorst segment: {:.1f}% — {}.\n",
                      100 * worst,
                      all_pass ? "all segments within tolerance"
                               : "NOT all within tolerance");
    WriteFileAtomic(ctx.output_dir / "realism.md", md.str());
    WriteFileAtomic(ctx.output_dir / "realism.csv", csv.str());
    SOMA_LOG(INFO,
             "realism: worst segment error {:.1f}% (tolerance {:.0f}%): {}",
             100 * worst,
             100 * options_.tolerance,
             all_pass ? "PASS" : "FAIL");
    ctx.ReportMetric("worst_segment_error", worst);
    ctx.ReportMetric("pass", all_pass ? 1.0 : 0.0);
  }

 private:
  RealismOptions options_;
};

}  // namespace

void RegisterRealismTask(Registry<Task>& registry) {
  registry.Register("realism", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    RealismOptions options;
    reader.Require("files", &options.files);
    reader.Read("tolerance", &options.tolerance);
    reader.Read("frame_stride", &options.frame_stride);
    reader.Check("files", !options.files.empty(), "at least one C3D file");
    reader.Check("tolerance", options.tolerance > 0, "tolerance > 0");
    reader.Check(
        "frame_stride", options.frame_stride >= 1, "frame_stride >= 1");
    reader.Finish();
    return std::make_unique<RealismTask>(options);
  });
}

}  // namespace soma
