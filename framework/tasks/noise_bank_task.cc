// `soma noise_bank`: SOMA's AMASS marker noise model from body fits
// (REFERENCE.md 3.4; framework/synth/noise_bank.h). Reads `soma solve`
// outputs of real takes (`task.fits`, all solved with one layout), takes
// the residual observed - simulated of every label in every usable frame,
// and writes the bank the `real_noise` module samples from:
//
//   soma noise_bank 'task.fits=[a/a_stageii.h5,b/b_stageii.h5]'
//   soma train noise=real_noise noise.modules.0.path=<run>/noise_bank.h5
//
// Writes noise_bank.h5 (or task.output) and noise_bank.csv (per label: the
// residuals found, median and 95th percentile of their length in mm), and
// reports rows, labels with residuals and the median residual. Labels no
// fit observed get zero residuals (BuildNoiseBank) and are listed.
#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/logging.h"
#include "framework/core/random.h"
#include "framework/registry/registry.h"
#include "framework/solve/solve_output.h"
#include "framework/synth/noise_bank.h"
#include "framework/tasks/task.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace soma {
namespace {

struct NoiseBankOptions {
  std::vector<std::string> fits;
  std::string output = "noise_bank.h5";
};

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return std::nan("");
  const size_t k =
      std::min(values.size() - 1, static_cast<size_t>(q * (values.size() - 1)));
  std::nth_element(values.begin(), values.begin() + k, values.end());
  return values[k];
}

class NoiseBankTask : public Task {
 public:
  explicit NoiseBankTask(NoiseBankOptions options)
      : options_(std::move(options)) {}

  void Run(const ConfigNode& /*cfg*/, RunContext& ctx) override {
    std::vector<std::string> labels;
    std::vector<float> observed;
    std::vector<float> simulated;
    std::vector<std::vector<double>> lengths;  // per label, metres
    int64_t frames = 0;
    for (const std::string& path : options_.fits) {
      const SolveOutput fit = ReadSolveOutput(path);
      if (labels.empty()) {
        labels = fit.labels;
        lengths.resize(labels.size());
      } else if (fit.labels != labels) {
        throw ShapeError(fmt::format(
            "noise_bank: {} was solved with other labels than {} (solve "
            "every take with the same layout)",
            path,
            options_.fits.front()));
      }
      int64_t used = 0;
      for (size_t t = 0; t < fit.observed.size(); ++t) {
        if (!fit.summaries[t].usable()) continue;
        ++used;
        for (size_t l = 0; l < labels.size(); ++l) {
          const Eigen::Vector3d o = fit.observed[t].col(l);
          const Eigen::Vector3d s = fit.simulated[t].col(l);
          const bool both = o.allFinite() && s.allFinite();
          for (int i = 0; i < 3; ++i) {
            observed.push_back(both ? static_cast<float>(o[i]) : 0.0f);
            simulated.push_back(both ? static_cast<float>(s[i]) : 0.0f);
          }
          if (both) lengths[l].push_back((o - s).norm());
        }
      }
      frames += used;
      SOMA_LOG(INFO, "noise_bank: {}: {} usable frames", path, used);
    }
    Rng rng = Rng(ctx.seed).Stream("noise_bank");
    const NoiseBank bank = BuildNoiseBank(labels, observed, simulated, rng);
    std::filesystem::path output(options_.output);
    if (output.is_relative()) output = ctx.output_dir / output;
    WriteNoiseBank(bank, output);

    std::ostringstream csv;
    csv << "label,residuals,median_mm,p95_mm\n";
    std::vector<std::string> empty;
    std::vector<double> all;
    for (size_t l = 0; l < labels.size(); ++l) {
      csv << fmt::format("{},{},{:.2f},{:.2f}\n",
                         labels[l],
                         lengths[l].size(),
                         1e3 * Quantile(lengths[l], 0.5),
                         1e3 * Quantile(lengths[l], 0.95));
      if (lengths[l].empty()) empty.push_back(labels[l]);
      all.insert(all.end(), lengths[l].begin(), lengths[l].end());
    }
    WriteFileAtomic(ctx.output_dir / "noise_bank.csv", csv.str());
    if (!empty.empty()) {
      SOMA_LOG(WARNING,
               "noise_bank: {} labels were never observed and get zero "
               "residuals: {}",
               empty.size(),
               fmt::join(empty, " "));
    }
    SOMA_LOG(INFO,
             "noise_bank: wrote {} ({} rows x {} labels from {} frames; "
             "median residual {:.1f} mm)",
             output.string(),
             bank.num_rows,
             bank.num_labels(),
             frames,
             1e3 * Quantile(all, 0.5));
    ctx.ReportMetric("rows", static_cast<double>(bank.num_rows));
    ctx.ReportMetric("frames", static_cast<double>(frames));
    ctx.ReportMetric("labels_observed",
                     static_cast<double>(labels.size() - empty.size()));
    ctx.ReportMetric("median_residual_mm", 1e3 * Quantile(all, 0.5));
  }

 private:
  NoiseBankOptions options_;
};

}  // namespace

void RegisterNoiseBankTask(Registry<Task>& registry) {
  registry.Register("noise_bank", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    NoiseBankOptions o;
    reader.RequireOneOrMore("fits", &o.fits);
    reader.Read("output", &o.output);
    reader.Check("fits", !o.fits.empty(), "one or more `soma solve` outputs");
    reader.Finish();
    return std::make_unique<NoiseBankTask>(std::move(o));
  });
}

}  // namespace soma
