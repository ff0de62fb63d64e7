// The results table of a reproduction: our numbers (mean ± std over training
// seeds, and separately the mean over seeds of the std over frames) beside the
// paper's, the paper's claims checked with the measured gap, and a header
// that says what was run and how it differs from the paper.
//
// Files (written atomically):
//  - `<name>.csv`: one row per (variant, test, metric): table, variant,
//    variant_label, test, test_label, setting, mode, metric, seeds_done,
//    seeds_planned, mean, std_seeds, std_frames, paper, paper_std, status
//    (done | partial | not run | skipped), note. Values in percent; empty
//    cells where there is no value.
//  - `<name>.md`: the header, the table, the claims, the differences. A
//    report written from a checkout with uncommitted changes (a commit
//    "<sha>-dirty") says so in its first lines (kDirtyTreeMark).
//  - `<name>_seeds.csv`: one row per (variant, test, metric, training seed),
//    the per-seed values behind every mean and ± of `<name>.csv`.
#pragma once

#include "framework/reproduce/ablation_spec.h"

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace soma {

/// Our values for one (variant, test, metric): one entry per finished seed.
struct CellResult {
  std::string variant;
  std::string test;
  std::string metric;
  std::vector<double> seed_means;       // per-frame mean of each seed, %
  std::vector<double> seed_frame_stds;  // std over frames of each seed, %
  std::vector<int> seeds;  // the training seed of each entry (may be empty)
  int seeds_planned = 0;

  int seeds_done() const { return static_cast<int>(seed_means.size()); }
  /// Mean over seeds; nullopt without a finished seed.
  std::optional<double> Mean() const;
  /// Sample std (ddof 1) over seeds; nullopt with fewer than two seeds.
  std::optional<double> SeedStd() const;
  /// Mean over seeds of the std over frames.
  std::optional<double> FrameStd() const;
};

struct ClaimOutcome {
  const AblationClaim* claim = nullptr;
  std::optional<double> gap;  // ours: better - worse, points
  /// Standard error of `gap`. Paired when both sides are the same variant
  /// (the same models, tested twice) and share >= 2 seeds: the std of the
  /// per-seed differences / sqrt(n), over the shared seeds. Otherwise from
  /// the seed spread of both sides (sqrt(s_b^2/n_b + s_w^2/n_w)); a side with
  /// one seed borrows the other side's s; nullopt when neither side has two
  /// seeds.
  std::optional<double> gap_se;
  bool paired = false;              // gap_se is the paired one
  std::optional<double> paper_gap;  // the paper's, when known
  std::string verdict;  // pass | fail | not run | skipped (a skipped row)
  /// The verdict is not resolved by this many seeds: the claim's boundary
  /// (0 for greater, ±tolerance for close) lies within 2 standard errors of
  /// the gap, so a rerun with other seeds could flip it.
  bool within_noise = false;
};

/// The first words of the line a report written from a dirty tree carries
/// under its title; tests/reproduce/results_test.cc fails on a committed
/// report that names a "-dirty" commit without it.
inline constexpr const char* kDirtyTreeMark = "**DIRTY TREE:";

/// Claims counted by whose they are (AblationClaim::origin) and verdict.
struct ClaimCounts {
  int claims = 0;
  int pass = 0;
  int fail = 0;
  int not_run = 0;
  int skipped = 0;       // a claim on a row this reproduction skips
  int within_noise = 0;  // verdicts (pass or fail) within seed noise
};

/// Checks every claim of `spec` on `cells` (greater: gap > 0; close: |gap| <=
/// tolerance). A claim whose cells have no finished seed is "not run". The
/// verdict is about the means; `within_noise` flags a verdict whose boundary
/// is under 2 standard errors from the gap.
/// The outcomes point at `spec`'s claims, so `spec` must outlive them (a
/// temporary spec is refused at compile time).
std::vector<ClaimOutcome> CheckClaims(const AblationSpec& spec,
                                      const std::vector<CellResult>& cells);
std::vector<ClaimOutcome> CheckClaims(
    AblationSpec&& spec, const std::vector<CellResult>& cells) = delete;

/// `outcomes` counted for one origin ("paper", "ours", "duplicate").
ClaimCounts CountClaims(const std::vector<ClaimOutcome>& outcomes,
                        const std::string& origin);

/// One sentence: "13 claims: 6 of the paper's own (4 pass, 2 fail; 3 within
/// seed noise), 2 of ours (2 pass, 0 fail; 0 within seed noise), 5 paper's
/// claims repeated on another take (...)". Origins without claims are left
/// out.
std::string ClaimsSummary(const std::vector<ClaimOutcome>& outcomes);

/// What the header states.
struct ReportContext {
  std::string command;  // the exact command line
  std::string commit;   // git SHA (+ "-dirty": the report says so on top)
  std::string date;
  std::string machine;  // where the report was written: host, CPU, threads
  /// Where the trained models ran (TrainingMachines): "vm, Intel(R) Xeon(R)
  /// Processor: 12 models"; the row is left out when empty.
  std::vector<std::string> trained_on;
  std::vector<std::string> budget;  // overrides of every training
  std::string data_dir;             // where the takes were read
  double compute_s = 0;             // summed wall time of all commands
  int models_done = 0;
  int models_planned = 0;
  int seeds = 0;  // training seeds per variant planned (0: the spec's)
};

void WriteResultsCsv(const AblationSpec& spec,
                     const std::vector<CellResult>& cells,
                     const std::filesystem::path& path);

/// The claim's test as text: "base − no_transformer > 0", or
/// "|a@t0 − a@t5| ≤ 2.0" for a close claim across two tests.
std::string ClaimRule(const AblationClaim& claim);

/// One row per claim of `spec` (results/<name>_claims.csv): table, claim,
/// rule, kind, metric, better, better_test, worse, worse_test, tolerance
/// (close claims), paper_gap, gap, gap_se, paired (1/0), verdict
/// (pass|fail|not run), within_noise (1/0, for greater and close claims
/// alike), paper_note, origin (paper|ours|duplicate). Gaps are in points;
/// empty cells are unknown (no paper gap, not run, fewer than two seeds).
void WriteClaimsCsv(const AblationSpec& spec,
                    const std::vector<CellResult>& cells,
                    const std::filesystem::path& path);

/// One row per finished (variant, test, metric, seed)
/// (results/<name>_seeds.csv): table, variant, test, metric, seed, value
/// (the per-frame mean over the take, %), std_frames (%). The seed column is
/// empty where the cell does not know its seeds.
void WriteSeedsCsv(const AblationSpec& spec,
                   const std::vector<CellResult>& cells,
                   const std::filesystem::path& path);

void WriteResultsMarkdown(const AblationSpec& spec,
                          const std::vector<CellResult>& cells,
                          const ReportContext& context,
                          const std::filesystem::path& path);

}  // namespace soma
