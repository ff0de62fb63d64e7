#include "framework/train/schedule.h"

#include "framework/config/decode.h"
#include "framework/core/error.h"
#include "framework/registry/registry.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>

namespace soma {
namespace {

// State text: one `key=value` per line; doubles in fmt's shortest
// round-trip form (`inf`, `nan` included).
std::map<std::string, std::string, std::less<>> ParseState(
    std::string_view text, std::string_view what) {
  std::map<std::string, std::string, std::less<>> out;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    const std::string_view line = text.substr(pos, end - pos);
    pos = end + 1;
    if (line.empty()) continue;
    const size_t eq = line.find('=');
    if (eq == std::string_view::npos) {
      throw InternalError(
          fmt::format("{} state: malformed line '{}'", what, line));
    }
    out.emplace(std::string(line.substr(0, eq)),
                std::string(line.substr(eq + 1)));
  }
  return out;
}

const std::string& Field(
    const std::map<std::string, std::string, std::less<>>& state,
    std::string_view key,
    std::string_view what) {
  auto it = state.find(key);
  if (it == state.end()) {
    throw InternalError(fmt::format("{} state: missing '{}'", what, key));
  }
  return it->second;
}

double ToDouble(const std::string& text) {
  return std::strtod(text.c_str(), nullptr);
}

int64_t ToInt(const std::string& text) {
  return std::strtoll(text.c_str(), nullptr, 10);
}

}  // namespace

void PlateauOptions::Validate() const {
  if (!(factor > 0 && factor < 1)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. scheduler.factor = {}. Violated constraint: "
        "0 < factor < 1",
        factor));
  }
  if (patience < 0 || cooldown < 0 || threshold < 0 || min_lr < 0 || eps < 0) {
    throw ConfigError(
        "Invalid configuration. scheduler: patience, cooldown, threshold, "
        "min_lr and eps must be >= 0");
  }
}

ReduceLrOnPlateau::ReduceLrOnPlateau(const PlateauOptions& options)
    : options_(options) {
  options_.Validate();
}

double ReduceLrOnPlateau::Step(double metric, double lr) {
  ++last_epoch_;
  // PyTorch: is_better(a, best) = a < best * (1 - threshold) (mode min, rel).
  if (metric < best_ * (1.0 - options_.threshold)) {
    best_ = metric;
    num_bad_epochs_ = 0;
  } else {
    ++num_bad_epochs_;
  }
  if (cooldown_counter_ > 0) {
    --cooldown_counter_;
    num_bad_epochs_ = 0;
  }
  if (num_bad_epochs_ > options_.patience) {
    const double new_lr = std::max(lr * options_.factor, options_.min_lr);
    if (lr - new_lr > options_.eps) lr = new_lr;
    cooldown_counter_ = options_.cooldown;
    num_bad_epochs_ = 0;
  }
  return lr;
}

std::string ReduceLrOnPlateau::SaveState() const {
  return fmt::format(
      "best={}\nnum_bad_epochs={}\ncooldown_counter={}\nlast_epoch={}\n",
      best_,
      num_bad_epochs_,
      cooldown_counter_,
      last_epoch_);
}

void ReduceLrOnPlateau::LoadState(std::string_view text) {
  constexpr std::string_view kWhat = "ReduceLROnPlateau";
  const auto state = ParseState(text, kWhat);
  best_ = ToDouble(Field(state, "best", kWhat));
  num_bad_epochs_ =
      static_cast<int>(ToInt(Field(state, "num_bad_epochs", kWhat)));
  cooldown_counter_ =
      static_cast<int>(ToInt(Field(state, "cooldown_counter", kWhat)));
  last_epoch_ = ToInt(Field(state, "last_epoch", kWhat));
}

void CosineOptions::Validate() const {
  if (warmup_steps < 0) {
    throw ConfigError(fmt::format(
        "Invalid configuration. scheduler.warmup_steps = {}. Violated "
        "constraint: warmup_steps >= 0",
        warmup_steps));
  }
  if (!(final_factor >= 0 && final_factor <= 1)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. scheduler.final_factor = {}. Violated "
        "constraint: 0 <= final_factor <= 1",
        final_factor));
  }
}

WarmupCosineLr::WarmupCosineLr(const CosineOptions& options)
    : options_(options) {
  options_.Validate();
}

double WarmupCosineLr::StepLr(int64_t step,
                              int64_t total_steps,
                              double epoch_lr) const {
  const int64_t warmup = options_.warmup_steps;
  if (step < warmup) {
    return epoch_lr * static_cast<double>(step + 1) /
           static_cast<double>(warmup);
  }
  const int64_t span = total_steps - warmup;
  const double progress = span > 0
                              ? std::clamp(static_cast<double>(step - warmup) /
                                               static_cast<double>(span),
                                           0.0,
                                           1.0)
                              : 1.0;
  const double f = options_.final_factor;
  return epoch_lr * (f + (1.0 - f) * 0.5 * (1.0 + std::cos(M_PI * progress)));
}

void EarlyStoppingOptions::Validate() const {
  if (patience < 1) {
    throw ConfigError(fmt::format(
        "Invalid configuration. train.early_stopping.patience = {}. Violated "
        "constraint: patience >= 1",
        patience));
  }
  if (!(min_delta >= 0)) {
    throw ConfigError(fmt::format(
        "Invalid configuration. train.early_stopping.min_delta = {}. "
        "Violated constraint: min_delta >= 0",
        min_delta));
  }
}

EarlyStopping::EarlyStopping(const EarlyStoppingOptions& options)
    : options_(options) {
  options_.Validate();
}

bool EarlyStopping::Update(double metric) {
  if (!options_.enabled || stopped_) return stopped_;
  if (options_.check_finite && !std::isfinite(metric)) {
    stopped_ = true;
    reason_ = fmt::format("monitored val_loss = {} is not finite", metric);
    return true;
  }
  if (metric < best_ - options_.min_delta) {
    best_ = metric;
    wait_count_ = 0;
  } else {
    ++wait_count_;
    if (wait_count_ >= options_.patience) {
      stopped_ = true;
      reason_ = fmt::format(
          "val_loss did not improve in the last {} epochs (best {})",
          wait_count_,
          best_);
    }
  }
  return stopped_;
}

std::string EarlyStopping::SaveState() const {
  return fmt::format("best={}\nwait_count={}\nstopped={}\nreason={}\n",
                     best_,
                     wait_count_,
                     stopped_ ? 1 : 0,
                     reason_);
}

void EarlyStopping::LoadState(std::string_view text) {
  constexpr std::string_view kWhat = "EarlyStopping";
  const auto state = ParseState(text, kWhat);
  best_ = ToDouble(Field(state, "best", kWhat));
  wait_count_ = static_cast<int>(ToInt(Field(state, "wait_count", kWhat)));
  stopped_ = ToInt(Field(state, "stopped", kWhat)) != 0;
  reason_ = Field(state, "reason", kWhat);
}

PlateauOptions DecodePlateauOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  PlateauOptions options;
  std::string mode = "min";
  std::string threshold_mode = "rel";
  reader.Read("mode", &mode);
  reader.Read("threshold_mode", &threshold_mode);
  reader.Read("factor", &options.factor);
  reader.Read("patience", &options.patience);
  reader.Read("threshold", &options.threshold);
  reader.Read("cooldown", &options.cooldown);
  reader.Read("min_lr", &options.min_lr);
  reader.Read("eps", &options.eps);
  reader.Check("mode", mode == "min", "mode == min (val_loss is minimised)");
  reader.Check(
      "threshold_mode", threshold_mode == "rel", "threshold_mode == rel");
  reader.Check(
      "factor", options.factor > 0 && options.factor < 1, "0 < factor < 1");
  reader.Check("patience", options.patience >= 0, "patience >= 0");
  reader.Check("threshold", options.threshold >= 0, "threshold >= 0");
  reader.Check("cooldown", options.cooldown >= 0, "cooldown >= 0");
  reader.Check("min_lr", options.min_lr >= 0, "min_lr >= 0");
  reader.Check("eps", options.eps >= 0, "eps >= 0");
  reader.Finish();
  return options;
}

CosineOptions DecodeCosineOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  CosineOptions options;
  reader.Read("warmup_steps", &options.warmup_steps);
  reader.Read("final_factor", &options.final_factor);
  reader.Check("warmup_steps", options.warmup_steps >= 0, "warmup_steps >= 0");
  reader.Check("final_factor",
               options.final_factor >= 0 && options.final_factor <= 1,
               "0 <= final_factor <= 1");
  reader.Finish();
  return options;
}

EarlyStoppingOptions DecodeEarlyStoppingOptions(const ConfigNode& node) {
  ConfigReader reader(node);
  EarlyStoppingOptions options;
  std::string monitor = "val_loss";
  std::string mode = "min";
  reader.Read("enabled", &options.enabled);
  reader.Read("monitor", &monitor);
  reader.Read("mode", &mode);
  reader.Read("patience", &options.patience);
  reader.Read("min_delta", &options.min_delta);
  reader.Read("check_finite", &options.check_finite);
  reader.Check("monitor", monitor == "val_loss", "monitor == val_loss");
  reader.Check("mode", mode == "min", "mode == min");
  reader.Check("patience", options.patience >= 1, "patience >= 1");
  reader.Check("min_delta", options.min_delta >= 0, "min_delta >= 0");
  reader.Finish();
  return options;
}

void RegisterSchedulers() {
  Registry<LrScheduler>& registry = GetRegistry<LrScheduler>();
  registry.Register("plateau", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<ReduceLrOnPlateau>(DecodePlateauOptions(node));
  });
  registry.Register("cosine", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<WarmupCosineLr>(DecodeCosineOptions(node));
  });
  registry.Register("none", [](const ConfigNode& node, BuildContext&) {
    ConfigReader reader(node);
    reader.Finish();
    return std::make_unique<ConstantLr>();
  });
  RegisterConfigGroup<LrScheduler>("scheduler");
}

}  // namespace soma
