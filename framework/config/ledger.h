// The sweep ledger (HYDRA.md section 11): one entry per job of a multirun,
// kept at the sweep root as `jobs.yaml` (authoritative) and `jobs.csv`
// (a table with the metrics). Re-running the same multirun skips jobs whose
// config hash is `done` and re-runs failed or unfinished (`running`) ones.
// Also builds the seed-aggregated `summary.csv` / `summary.md`.
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace soma {

enum class JobStatus { kPending, kRunning, kDone, kFailed };

std::string_view ToString(JobStatus status);
JobStatus JobStatusFromString(std::string_view text);

struct LedgerEntry {
  int num = 0;
  std::vector<std::string> overrides;
  std::string config_hash;  // hash of the job's composed task config
  std::string dir;          // job output directory
  JobStatus status = JobStatus::kPending;
  int attempts = 0;  // how many times the job was started
  double wall_time_s = 0;
  std::string error;  // one-line error of the last failed attempt
  std::map<std::string, double> metrics;
};

class Ledger {
 public:
  /// Loads `<sweep_dir>/jobs.yaml` if it exists (else an empty ledger).
  /// A malformed ledger is an IoError naming the file.
  static Ledger Load(const std::filesystem::path& sweep_dir);

  /// Writes jobs.yaml and jobs.csv atomically.
  void Save() const;

  /// The entry for job `num` (created if absent).
  LedgerEntry& Entry(int num);
  const LedgerEntry* Find(int num) const;
  /// True if job `num` is recorded as done with the same config hash.
  bool IsDone(int num, const std::string& config_hash) const;

  const std::vector<LedgerEntry>& entries() const { return entries_; }
  const std::filesystem::path& sweep_dir() const { return sweep_dir_; }

 private:
  std::filesystem::path sweep_dir_;
  std::vector<LedgerEntry> entries_;  // sorted by num
};

/// An exclusive advisory lock (flock) on `<sweep_dir>/jobs.lock`, held for
/// its lifetime. Processes that update one ledger concurrently (the SLURM
/// launcher's array tasks, `soma sweep`) load, modify and save it under it.
class LedgerLock {
 public:
  explicit LedgerLock(const std::filesystem::path& sweep_dir);
  LedgerLock(const LedgerLock&) = delete;
  LedgerLock& operator=(const LedgerLock&) = delete;
  ~LedgerLock();

 private:
  int fd_ = -1;
};

/// One row of the seed aggregation: jobs that differ only by `seed`.
struct SummaryRow {
  std::vector<std::string> overrides;  // without seed=...
  int num_done = 0;
  int num_total = 0;
  /// metric -> (mean, sample std over seeds; NaN std when only one seed).
  std::map<std::string, std::pair<double, double>> metrics;
};

/// Groups ledger entries by their non-seed overrides (keys `seed`, `+seed`,
/// `++seed`), in first-appearance order, aggregating metrics of done jobs.
/// Overrides common to every job are left out of the row keys.
std::vector<SummaryRow> SummarizeBySeed(
    const std::vector<LedgerEntry>& entries);

/// Writes `summary.csv` and `summary.md` (mean ± std over seeds) into
/// `sweep_dir`.
void WriteSummary(const std::filesystem::path& sweep_dir,
                  const std::vector<SummaryRow>& rows);

}  // namespace soma
