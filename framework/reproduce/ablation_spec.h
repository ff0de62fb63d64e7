// An ablation spec: one paper table or figure as data (ablations/<name>.yaml;
// format in ablations/README.md). Variants are sets of training overrides,
// tests are real takes corrupted with one setting of SOMA's protocol and
// labelled per frame or by tracklet, claims are the paper's qualitative
// statements as comparisons between cells of the table.
#pragma once

#include "framework/config/node.h"

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace soma {

/// The metrics a reproduction reports per test (per-frame mean over a take,
/// in percent): accuracy and macro F1 (REFERENCE.md 4).
inline const std::vector<std::string>& ReproductionMetrics() {
  static const std::vector<std::string> kMetrics = {"acc", "f1"};
  return kMetrics;
}

/// A published number: mean and (if the paper gives one) its ± (the paper's
/// ± is the std over frames).
struct PaperValue {
  double mean = 0.0;
  std::optional<double> std;
};

struct AblationVariant {
  std::string name;   // identifier, [a-z0-9_]
  std::string label;  // row label in the table
  /// Training overrides on top of the reproduction's budget (e.g.
  /// `normalization=log_softmax`).
  std::vector<std::string> overrides;
  /// Non-empty: this row cannot run here; the reason is printed instead.
  std::string skip;
  /// Non-empty: the row is skipped when the budget sets this key (an
  /// override `<key>=...` or `<key>.<sub>=...`): a row that varies what the
  /// budget already fixes for every row (ApplyBudget).
  std::string skip_if_budget_sets;
  /// The tests this variant is evaluated on; empty: every test.
  std::vector<std::string> tests;
  /// test name -> metric -> the paper's value.
  std::map<std::string, std::map<std::string, PaperValue>> paper;

  /// The variant is evaluated on `test` (`tests` is empty or names it).
  bool Evaluates(const std::string& test) const;
};

struct AblationTest {
  std::string name;
  std::string label;
  std::string take;     // a C3D file, relative to the data dir
  std::string setting;  // `soma corrupt` setting, e.g. OC_05_G_03_BT_00
  bool tracklet = false;
  /// Extra overrides of the `soma corrupt` command, e.g.
  /// `layout.exclude=[RBAC,LSHN,RSHN]` (markers removed from the take).
  std::vector<std::string> corrupt_overrides;
  /// Extra overrides of each `soma eval` command, e.g.
  /// `task.unknown_gt_labels=ghost`.
  std::vector<std::string> eval_overrides;
  /// Extra overrides of each `soma label` command, e.g. `layout=cmu41` (the
  /// layout a layout-conditioned model labels the take with).
  std::vector<std::string> label_overrides;
};

/// "`better` beats `worse` on `test`/`metric`" (kind greater), "`better`
/// is within `tolerance` points of `worse`" (kind close: |gap| <= tolerance),
/// or "`worse` is at most `tolerance` points behind `better`" (kind
/// not_behind: gap <= tolerance, so `worse` may also be ahead; e.g. "one
/// conditioned model within 3 points of the per-layout model" as an
/// accuracy target, which a model that beats the per-layout one meets). The
/// two sides may
/// be read on different tests (`better_test`, `worse_test`; default `test`),
/// e.g. "0 occlusions vs 5 occlusions" for one variant.
struct AblationClaim {
  std::string text;
  std::string test;
  std::string better_test;  // defaults to `test`
  std::string worse_test;   // defaults to `test`
  std::string metric = "acc";
  std::string kind = "greater";  // greater | close | not_behind
  std::string better;
  std::string worse;
  double tolerance = 0.0;  // kinds close and not_behind: points
  /// The paper's gap (better - worse) when the paper gives no table numbers
  /// for it; otherwise computed from the variants' paper values.
  std::optional<double> paper_gap;
  std::string paper_note;  // e.g. "read off Fig. C.1"
  /// Whose claim it is, so that summaries count the paper's claims apart:
  /// "paper" (one of the paper's statements), "ours" (a claim of ours, not
  /// in the paper) or "duplicate" (a paper's claim checked a second time,
  /// on another take, e.g. Table 5's HDM05 claims repeated on the CMU take).
  std::string origin = "paper";
};

/// A difference from the paper's setup, printed in the report. Some hold
/// only under the default budget: "trains on the cmu41 layout" is false for
/// a run whose budget sets `layout`.
struct AblationDifference {
  std::string text;
  /// Non-empty: printed only if the budget sets this key (an override
  /// `<key>=...` or `<key>.<sub>=...`).
  std::string if_budget_sets;
  /// Non-empty: printed only if the budget does not set this key.
  std::string unless_budget_sets;

  bool AppliesTo(const std::vector<std::string>& budget) const;
};

struct AblationSpec {
  std::string name;
  std::string title;
  std::string paper_ref;    // e.g. "SOMA (ICCV 2021), Table 5"
  std::string description;  // what is measured, in a sentence or two
  int seeds = 3;
  std::vector<AblationDifference> differences;  // from the paper's setup
  std::vector<AblationVariant> variants;
  std::vector<AblationTest> tests;
  std::vector<AblationClaim> claims;

  const AblationVariant& Variant(const std::string& name) const;
  const AblationTest& Test(const std::string& name) const;
};

/// `spec` as run under `budget`: each variant whose skip_if_budget_sets key
/// the budget sets is skipped, with the reason.
AblationSpec ApplyBudget(AblationSpec spec,
                         const std::vector<std::string>& budget);

/// Decodes and validates a spec (unknown keys, duplicate names, claims naming
/// unknown variants/tests/metrics: ConfigError naming `source` and the key).
AblationSpec ParseAblationSpec(const ConfigNode& node,
                               const std::string& source);

/// Loads `<name>.yaml` from `dir`, or `name` itself when it is a path to a
/// .yaml file. IoError listing the available specs when it does not exist.
AblationSpec LoadAblationSpec(const std::string& name,
                              const std::filesystem::path& dir);

/// The spec names (file stems) in `dir`, sorted.
std::vector<std::string> ListAblationSpecs(const std::filesystem::path& dir);

}  // namespace soma
