#include "framework/config/ledger.h"

#include "framework/config/node.h"
#include "framework/config/yaml_io.h"
#include "framework/core/csv.h"
#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <fcntl.h>
#include <set>
#include <sstream>
#include <sys/file.h>
#include <unistd.h>

namespace soma {
namespace {

constexpr char kLedgerFile[] = "jobs.yaml";

std::string FormatMetric(double value) {
  if (std::isnan(value)) return "nan";
  return fmt::format("{:.6g}", value);
}

bool IsSeedOverride(const std::string& override_text) {
  std::string_view text(override_text);
  while (!text.empty() && (text.front() == '+' || text.front() == '~')) {
    text.remove_prefix(1);
  }
  return text.substr(0, 5) == "seed=";
}

}  // namespace

std::string_view ToString(JobStatus status) {
  switch (status) {
    case JobStatus::kPending:
      return "pending";
    case JobStatus::kRunning:
      return "running";
    case JobStatus::kDone:
      return "done";
    case JobStatus::kFailed:
      return "failed";
  }
  return "pending";
}

JobStatus JobStatusFromString(std::string_view text) {
  if (text == "pending") return JobStatus::kPending;
  if (text == "running") return JobStatus::kRunning;
  if (text == "done") return JobStatus::kDone;
  if (text == "failed") return JobStatus::kFailed;
  throw IoError(fmt::format(
      "Invalid job status '{}'; expected pending, running, done or failed",
      text));
}

Ledger Ledger::Load(const std::filesystem::path& sweep_dir) {
  Ledger ledger;
  ledger.sweep_dir_ = sweep_dir;
  const std::filesystem::path path = sweep_dir / kLedgerFile;
  if (!std::filesystem::exists(path)) return ledger;
  try {
    const ConfigNode root = ParseYaml(ReadFile(path), path.string());
    const ConfigNode* jobs = root.Find("jobs");
    if (jobs == nullptr || !jobs->IsList()) {
      throw IoError("missing 'jobs' list");
    }
    for (const ConfigNode& job : jobs->items()) {
      LedgerEntry entry;
      entry.num = static_cast<int>(job.at("num").AsInt());
      for (const ConfigNode& o : job.at("overrides").items()) {
        entry.overrides.push_back(o.IsString() ? o.AsString() : o.text());
      }
      entry.config_hash = job.at("config_hash").AsString();
      entry.dir = job.at("dir").AsString();
      entry.status = JobStatusFromString(job.at("status").AsString());
      entry.attempts = static_cast<int>(job.at("attempts").AsInt());
      entry.wall_time_s = job.at("wall_time_s").AsDouble();
      if (const ConfigNode* error = job.Find("error");
          error && error->IsString()) {
        entry.error = error->AsString();
      }
      if (const ConfigNode* metrics = job.Find("metrics");
          metrics && metrics->IsMap()) {
        for (const auto& [name, value] : metrics->entries()) {
          entry.metrics[name] =
              value.IsString() ? std::nan("") : value.AsDouble();
        }
      }
      ledger.entries_.push_back(std::move(entry));
    }
  } catch (const Error& e) {
    throw IoError(fmt::format(
        "Malformed sweep ledger '{}': {}", path.string(), e.what()));
  }
  std::sort(
      ledger.entries_.begin(),
      ledger.entries_.end(),
      [](const LedgerEntry& a, const LedgerEntry& b) { return a.num < b.num; });
  return ledger;
}

LedgerEntry& Ledger::Entry(int num) {
  auto it = std::lower_bound(
      entries_.begin(), entries_.end(), num, [](const LedgerEntry& e, int n) {
        return e.num < n;
      });
  if (it != entries_.end() && it->num == num) return *it;
  LedgerEntry entry;
  entry.num = num;
  return *entries_.insert(it, std::move(entry));
}

const LedgerEntry* Ledger::Find(int num) const {
  for (const LedgerEntry& e : entries_) {
    if (e.num == num) return &e;
  }
  return nullptr;
}

bool Ledger::IsDone(int num, const std::string& config_hash) const {
  const LedgerEntry* e = Find(num);
  return e != nullptr && e->status == JobStatus::kDone &&
         e->config_hash == config_hash;
}

void Ledger::Save() const {
  ConfigNode root = ConfigNode::EmptyMap();
  ConfigNode jobs = ConfigNode::EmptyList();
  std::set<std::string> metric_names;
  for (const LedgerEntry& e : entries_) {
    ConfigNode job = ConfigNode::EmptyMap();
    job.Set("num", e.num);
    ConfigNode overrides = ConfigNode::EmptyList();
    for (const std::string& o : e.overrides) {
      overrides.Append(ConfigNode::LiteralString(o));
    }
    job.Set("overrides", overrides);
    job.Set("config_hash", ConfigNode::LiteralString(e.config_hash));
    job.Set("dir", ConfigNode::LiteralString(e.dir));
    job.Set("status",
            ConfigNode::LiteralString(std::string(ToString(e.status))));
    job.Set("attempts", e.attempts);
    job.Set("wall_time_s", e.wall_time_s);
    job.Set("error", ConfigNode::LiteralString(e.error));
    ConfigNode metrics = ConfigNode::EmptyMap();
    for (const auto& [name, value] : e.metrics) {
      metrics.Set(name,
                  std::isnan(value) ? ConfigNode::LiteralString("nan")
                                    : ConfigNode(value));
      metric_names.insert(name);
    }
    job.Set("metrics", metrics);
    jobs.Append(job);
  }
  root.Set("jobs", jobs);
  WriteFileAtomic(sweep_dir_ / kLedgerFile, DumpYaml(root));

  std::ostringstream csv;
  csv << "num,status,attempts,wall_time_s,config_hash,overrides";
  for (const std::string& name : metric_names) csv << "," << CsvField(name);
  csv << ",error\n";
  for (const LedgerEntry& e : entries_) {
    std::string overrides;
    for (size_t i = 0; i < e.overrides.size(); ++i) {
      overrides += (i ? " " : "") + e.overrides[i];
    }
    csv << e.num << "," << ToString(e.status) << "," << e.attempts << ","
        << fmt::format("{:.3f}", e.wall_time_s) << "," << e.config_hash << ","
        << CsvField(overrides);
    for (const std::string& name : metric_names) {
      auto it = e.metrics.find(name);
      csv << "," << (it == e.metrics.end() ? "" : FormatMetric(it->second));
    }
    csv << "," << CsvField(e.error) << "\n";
  }
  WriteFileAtomic(sweep_dir_ / "jobs.csv", csv.str());
}

LedgerLock::LedgerLock(const std::filesystem::path& sweep_dir) {
  const std::filesystem::path path = sweep_dir / "jobs.lock";
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    throw IoError(
        fmt::format("Cannot open the ledger lock '{}'", path.string()));
  }
  while (::flock(fd_, LOCK_EX) != 0) {
    if (errno != EINTR) {
      ::close(fd_);
      throw IoError(fmt::format("Cannot lock '{}'", path.string()));
    }
  }
}

LedgerLock::~LedgerLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the flock
}

std::vector<SummaryRow> SummarizeBySeed(
    const std::vector<LedgerEntry>& entries) {
  // Overrides shared by every job (e.g. task.steps=5 on the command line) say
  // nothing about a row; only the ones that vary across the sweep are shown.
  std::map<std::string, size_t> occurrences;
  for (const LedgerEntry& e : entries) {
    for (const std::string& o :
         std::set<std::string>(e.overrides.begin(), e.overrides.end())) {
      ++occurrences[o];
    }
  }
  std::vector<SummaryRow> rows;
  std::map<std::vector<std::string>, size_t> index;
  std::map<size_t, std::map<std::string, std::vector<double>>> values;
  for (const LedgerEntry& e : entries) {
    std::vector<std::string> key;
    for (const std::string& o : e.overrides) {
      if (IsSeedOverride(o)) continue;
      if (entries.size() > 1 && occurrences[o] == entries.size()) continue;
      key.push_back(o);
    }
    auto [it, inserted] = index.emplace(key, rows.size());
    if (inserted) {
      SummaryRow row;
      row.overrides = key;
      rows.push_back(row);
    }
    SummaryRow& row = rows[it->second];
    ++row.num_total;
    if (e.status != JobStatus::kDone) continue;
    ++row.num_done;
    for (const auto& [name, value] : e.metrics) {
      values[it->second][name].push_back(value);
    }
  }
  for (auto& [row_index, metrics] : values) {
    for (auto& [name, samples] : metrics) {
      double mean = 0;
      for (double v : samples) mean += v;
      mean /= samples.size();
      double std = std::nan("");
      if (samples.size() > 1) {
        double ss = 0;
        for (double v : samples) ss += (v - mean) * (v - mean);
        std = std::sqrt(ss / (samples.size() - 1));
      }
      rows[row_index].metrics[name] = {mean, std};
    }
  }
  return rows;
}

void WriteSummary(const std::filesystem::path& sweep_dir,
                  const std::vector<SummaryRow>& rows) {
  std::set<std::string> metric_names;
  for (const SummaryRow& row : rows) {
    for (const auto& [name, stats] : row.metrics) metric_names.insert(name);
  }
  std::ostringstream csv, md;
  csv << "overrides,seeds_done,seeds_total";
  md << "# Sweep summary\n\n"
     << "Mean ± sample standard deviation over seeds (jobs that differ only "
        "in `seed`); std is blank when only one seed finished.\n\n"
     << "| overrides | seeds done |";
  for (const std::string& name : metric_names) {
    csv << "," << CsvField(name + "_mean") << "," << CsvField(name + "_std");
    md << " " << name << " |";
  }
  csv << "\n";
  md << "\n|---|---|";
  for (size_t i = 0; i < metric_names.size(); ++i) md << "---|";
  md << "\n";
  for (const SummaryRow& row : rows) {
    std::string overrides;
    for (size_t i = 0; i < row.overrides.size(); ++i) {
      overrides += (i ? " " : "") + row.overrides[i];
    }
    csv << CsvField(overrides) << "," << row.num_done << "," << row.num_total;
    md << "| " << (overrides.empty() ? "(base)" : "`" + overrides + "`")
       << " | " << row.num_done << "/" << row.num_total << " |";
    for (const std::string& name : metric_names) {
      auto it = row.metrics.find(name);
      if (it == row.metrics.end()) {
        csv << ",,";
        md << " |";
        continue;
      }
      const auto [mean, std] = it->second;
      csv << "," << FormatMetric(mean) << ","
          << (std::isnan(std) ? "" : FormatMetric(std));
      md << " " << FormatMetric(mean)
         << (std::isnan(std) ? "" : " ± " + FormatMetric(std)) << " |";
    }
    csv << "\n";
    md << "\n";
  }
  WriteFileAtomic(sweep_dir / "summary.csv", csv.str());
  WriteFileAtomic(sweep_dir / "summary.md", md.str());
}

}  // namespace soma
