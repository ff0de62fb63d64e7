#include "framework/reproduce/report.h"

#include "framework/core/csv.h"
#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <cmath>
#include <numeric>
#include <sstream>

namespace soma {
namespace {

std::optional<double> MeanOf(const std::vector<double>& values) {
  if (values.empty()) return std::nullopt;
  return std::accumulate(values.begin(), values.end(), 0.0) /
         static_cast<double>(values.size());
}

const CellResult* FindCell(const std::vector<CellResult>& cells,
                           const std::string& variant,
                           const std::string& test,
                           const std::string& metric) {
  for (const CellResult& cell : cells) {
    if (cell.variant == variant && cell.test == test && cell.metric == metric)
      return &cell;
  }
  return nullptr;
}

const PaperValue* FindPaper(const AblationVariant& variant,
                            const std::string& test,
                            const std::string& metric) {
  const auto t = variant.paper.find(test);
  if (t == variant.paper.end()) return nullptr;
  const auto m = t->second.find(metric);
  return m == t->second.end() ? nullptr : &m->second;
}

/// Text for a markdown table cell: a '|' would end the cell, so it is
/// escaped (GitHub's tables accept "\|", also inside code spans).
std::string MarkdownCell(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    if (c == '|') out += '\\';
    out += c;
  }
  return out;
}

std::string Fixed(std::optional<double> value) {
  return value ? fmt::format("{:.2f}", *value) : "";
}

std::string Status(const AblationVariant& variant, const CellResult* cell) {
  if (!variant.skip.empty()) return "skipped";
  if (cell == nullptr || cell->seeds_done() == 0) return "not run";
  return cell->seeds_done() < cell->seeds_planned ? "partial" : "done";
}

/// "91.23 ± 1.05 (3 seeds) · frames ± 8.10".
std::string OursText(const AblationVariant& variant, const CellResult* cell) {
  if (!variant.skip.empty()) return "skipped";
  if (cell == nullptr || cell->seeds_done() == 0) return "not run";
  std::string text = fmt::format("{:.2f}", *cell->Mean());
  if (const auto s = cell->SeedStd()) text += fmt::format(" ± {:.2f}", *s);
  text +=
      fmt::format(" ({}/{} seeds)", cell->seeds_done(), cell->seeds_planned);
  return text;
}

std::string PaperText(const PaperValue* paper) {
  if (paper == nullptr) return "—";
  std::string text = fmt::format("{:.2f}", paper->mean);
  if (paper->std) text += fmt::format(" ± {:.2f}", *paper->std);
  return text;
}

std::string Signed(double value) { return fmt::format("{:+.2f}", value); }

std::string Duration(double seconds) {
  const int minutes = static_cast<int>(std::lround(seconds / 60.0));
  return minutes >= 60
             ? fmt::format("{} h {:02d} min", minutes / 60, minutes % 60)
             : fmt::format("{} min", minutes);
}

}  // namespace

std::optional<double> CellResult::Mean() const { return MeanOf(seed_means); }

std::optional<double> CellResult::SeedStd() const {
  if (seed_means.size() < 2) return std::nullopt;
  const double mean = *Mean();
  double ss = 0;
  for (double v : seed_means) ss += (v - mean) * (v - mean);
  return std::sqrt(ss / static_cast<double>(seed_means.size() - 1));
}

std::optional<double> CellResult::FrameStd() const {
  return MeanOf(seed_frame_stds);
}

std::string ClaimRule(const AblationClaim& claim) {
  const bool same_test = claim.better_test == claim.worse_test;
  const std::string better =
      same_test ? claim.better : claim.better + "@" + claim.better_test;
  const std::string worse =
      same_test ? claim.worse : claim.worse + "@" + claim.worse_test;
  if (claim.kind == "greater") {
    return fmt::format("{} − {} > 0", better, worse);
  }
  if (claim.kind == "not_behind") {
    return fmt::format("{} − {} ≤ {:.1f}", better, worse, claim.tolerance);
  }
  return fmt::format("|{} − {}| ≤ {:.1f}", better, worse, claim.tolerance);
}

std::vector<ClaimOutcome> CheckClaims(const AblationSpec& spec,
                                      const std::vector<CellResult>& cells) {
  std::vector<ClaimOutcome> outcomes;
  for (const AblationClaim& claim : spec.claims) {
    ClaimOutcome outcome;
    outcome.claim = &claim;
    outcome.paper_gap = claim.paper_gap;
    const PaperValue* paper_better =
        FindPaper(spec.Variant(claim.better), claim.better_test, claim.metric);
    const PaperValue* paper_worse =
        FindPaper(spec.Variant(claim.worse), claim.worse_test, claim.metric);
    if (!outcome.paper_gap && paper_better && paper_worse) {
      outcome.paper_gap = paper_better->mean - paper_worse->mean;
    }
    const CellResult* better =
        FindCell(cells, claim.better, claim.better_test, claim.metric);
    const CellResult* worse =
        FindCell(cells, claim.worse, claim.worse_test, claim.metric);
    if (better && worse && better->Mean() && worse->Mean()) {
      outcome.gap = *better->Mean() - *worse->Mean();
      // The same models tested twice: per-seed differences.
      std::vector<double> differences;
      if (claim.better == claim.worse) {
        for (size_t i = 0; i < better->seeds.size(); ++i) {
          for (size_t j = 0; j < worse->seeds.size(); ++j) {
            if (better->seeds[i] == worse->seeds[j] &&
                i < better->seed_means.size() && j < worse->seed_means.size()) {
              differences.push_back(better->seed_means[i] -
                                    worse->seed_means[j]);
            }
          }
        }
      }
      // With one seed on a side, assume that side has the other's spread.
      const std::optional<double> sb_opt = better->SeedStd();
      const std::optional<double> sw_opt = worse->SeedStd();
      if (differences.size() >= 2) {
        CellResult paired;
        paired.seed_means = differences;
        outcome.paired = true;
        outcome.gap_se = *paired.SeedStd() /
                         std::sqrt(static_cast<double>(differences.size()));
      } else if (sb_opt || sw_opt) {
        const double sb = sb_opt.value_or(*sw_opt);
        const double sw = sw_opt.value_or(*sb_opt);
        outcome.gap_se = std::sqrt(sb * sb / better->seeds_done() +
                                   sw * sw / worse->seeds_done());
      }
      const double gap = *outcome.gap;
      bool pass = false;
      double margin = 0;  // distance of the gap from the claim's boundary
      if (claim.kind == "greater") {
        pass = gap > 0;
        margin = std::abs(gap);
      } else if (claim.kind == "not_behind") {
        pass = gap <= claim.tolerance;
        margin = std::abs(gap - claim.tolerance);
      } else {
        pass = std::abs(gap) <= claim.tolerance;
        margin = std::abs(std::abs(gap) - claim.tolerance);
      }
      outcome.verdict = pass ? "pass" : "fail";
      if (outcome.gap_se) {
        outcome.within_noise = margin < 2 * *outcome.gap_se;
      }
    } else if (!spec.Variant(claim.better).skip.empty() ||
               !spec.Variant(claim.worse).skip.empty()) {
      outcome.verdict = "skipped";  // a row this reproduction does not train
    } else {
      outcome.verdict = "not run";
    }
    outcomes.push_back(outcome);
  }
  return outcomes;
}

void WriteResultsCsv(const AblationSpec& spec,
                     const std::vector<CellResult>& cells,
                     const std::filesystem::path& path) {
  std::ostringstream csv;
  csv << "table,variant,variant_label,test,test_label,setting,mode,metric,"
         "seeds_done,seeds_planned,mean,std_seeds,std_frames,paper,paper_std,"
         "status,note\n";
  for (const AblationVariant& variant : spec.variants) {
    for (const AblationTest& test : spec.tests) {
      if (!variant.Evaluates(test.name)) continue;
      for (const std::string& metric : ReproductionMetrics()) {
        const CellResult* cell =
            FindCell(cells, variant.name, test.name, metric);
        const PaperValue* paper = FindPaper(variant, test.name, metric);
        csv << fmt::format(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            spec.name,
            variant.name,
            CsvField(variant.label),
            test.name,
            CsvField(test.label),
            test.setting,
            test.tracklet ? "tracklet" : "per-frame",
            metric,
            cell ? cell->seeds_done() : 0,
            cell ? cell->seeds_planned : 0,
            Fixed(cell ? cell->Mean() : std::nullopt),
            Fixed(cell ? cell->SeedStd() : std::nullopt),
            Fixed(cell ? cell->FrameStd() : std::nullopt),
            paper ? fmt::format("{:.2f}", paper->mean) : "",
            paper ? Fixed(paper->std) : "",
            Status(variant, cell),
            CsvField(variant.skip));
      }
    }
  }
  WriteFileAtomic(path, csv.str());
}

void WriteClaimsCsv(const AblationSpec& spec,
                    const std::vector<CellResult>& cells,
                    const std::filesystem::path& path) {
  std::ostringstream csv;
  csv << "table,claim,rule,kind,metric,better,better_test,worse,worse_test,"
         "tolerance,paper_gap,gap,gap_se,paired,verdict,within_noise,"
         "paper_note,origin\n";
  for (const ClaimOutcome& outcome : CheckClaims(spec, cells)) {
    const AblationClaim& c = *outcome.claim;
    csv << fmt::format(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
        spec.name,
        CsvField(c.text),
        CsvField(ClaimRule(c)),
        c.kind,
        c.metric,
        c.better,
        c.better_test,
        c.worse,
        c.worse_test,
        c.kind != "greater" ? Fixed(c.tolerance) : "",
        Fixed(outcome.paper_gap),
        Fixed(outcome.gap),
        Fixed(outcome.gap_se),
        outcome.gap_se ? (outcome.paired ? "1" : "0") : "",
        outcome.verdict,
        outcome.gap ? (outcome.within_noise ? "1" : "0") : "",
        CsvField(c.paper_note),
        c.origin);
  }
  WriteFileAtomic(path, csv.str());
}

void WriteSeedsCsv(const AblationSpec& spec,
                   const std::vector<CellResult>& cells,
                   const std::filesystem::path& path) {
  std::ostringstream csv;
  csv << "table,variant,test,metric,seed,value,std_frames\n";
  for (const AblationVariant& variant : spec.variants) {
    for (const AblationTest& test : spec.tests) {
      if (!variant.Evaluates(test.name)) continue;
      for (const std::string& metric : ReproductionMetrics()) {
        const CellResult* cell =
            FindCell(cells, variant.name, test.name, metric);
        if (cell == nullptr) continue;
        for (size_t i = 0; i < cell->seed_means.size(); ++i) {
          csv << fmt::format(
              "{},{},{},{},{},{:.4f},{}\n",
              spec.name,
              variant.name,
              test.name,
              metric,
              i < cell->seeds.size() ? std::to_string(cell->seeds[i]) : "",
              cell->seed_means[i],
              i < cell->seed_frame_stds.size()
                  ? fmt::format("{:.4f}", cell->seed_frame_stds[i])
                  : "");
        }
      }
    }
  }
  WriteFileAtomic(path, csv.str());
}

ClaimCounts CountClaims(const std::vector<ClaimOutcome>& outcomes,
                        const std::string& origin) {
  ClaimCounts counts;
  for (const ClaimOutcome& outcome : outcomes) {
    if (outcome.claim->origin != origin) continue;
    ++counts.claims;
    counts.pass += outcome.verdict == "pass";
    counts.fail += outcome.verdict == "fail";
    counts.not_run += outcome.verdict == "not run";
    counts.skipped += outcome.verdict == "skipped";
    counts.within_noise += outcome.gap && outcome.within_noise;
  }
  return counts;
}

std::string ClaimsSummary(const std::vector<ClaimOutcome>& outcomes) {
  std::vector<std::string> parts;
  for (const auto& [origin, name] :
       {std::pair<std::string, std::string>{"paper", "of the paper's own"},
        {"ours", "of ours (not in the paper)"},
        {"duplicate", "paper's claims repeated on another take"}}) {
    const ClaimCounts c = CountClaims(outcomes, origin);
    if (c.claims == 0) continue;
    std::string text =
        fmt::format("{} {} ({} pass, {} fail", c.claims, name, c.pass, c.fail);
    if (c.not_run > 0) text += fmt::format(", {} not run", c.not_run);
    if (c.skipped > 0) text += fmt::format(", {} skipped", c.skipped);
    text += fmt::format("; {} within seed noise)", c.within_noise);
    parts.push_back(text);
  }
  return fmt::format("{} claims: {}", outcomes.size(), fmt::join(parts, ", "));
}

void WriteResultsMarkdown(const AblationSpec& spec,
                          const std::vector<CellResult>& cells,
                          const ReportContext& context,
                          const std::filesystem::path& path) {
  std::ostringstream md;
  const bool complete = context.models_done == context.models_planned;
  md << "# " << spec.title << "\n\n";
  if (context.commit.size() > 6 &&
      context.commit.compare(context.commit.size() - 6, 6, "-dirty") == 0) {
    md << kDirtyTreeMark
       << fmt::format(
              " written from a checkout with uncommitted changes (commit "
              "{}).** The code that made these numbers may be in no "
              "commit; regenerate the report from a clean tree.\n\n",
              context.commit);
  }
  if (!complete) {
    md << fmt::format(
        "**PARTIAL: {} of {} trainings finished.** Cells marked \"not run\" "
        "or with fewer seeds than planned are incomplete; re-run the "
        "command below to continue.\n\n",
        context.models_done,
        context.models_planned);
  }
  if (!spec.description.empty()) md << spec.description << "\n\n";
  md << "| | |\n|---|---|\n";
  md << "| reproduces | " << MarkdownCell(spec.paper_ref) << " |\n";
  md << "| command | `" << MarkdownCell(context.command) << "` |\n";
  md << "| training budget (every model) | `"
     << MarkdownCell(fmt::format("{}", fmt::join(context.budget, " ")))
     << "` |\n";
  md << "| seeds | " << (context.seeds > 0 ? context.seeds : spec.seeds)
     << " training seeds per variant";
  if (context.seeds > 0 && context.seeds != spec.seeds) {
    md << fmt::format(" (task.seeds; the spec plans {})", spec.seeds);
  }
  md << " |\n";
  md << "| test data | ";
  for (size_t i = 0; i < spec.tests.size(); ++i) {
    const AblationTest& t = spec.tests[i];
    md << (i ? "; " : "")
       << MarkdownCell(fmt::format(
              "{}: `{}` corrupted as `{}`, {}",
              t.name,
              t.take,
              t.setting,
              t.tracklet ? "tracklet labelling" : "per-frame labelling"));
  }
  md << " |\n";
  md << fmt::format(
      "| compute | {} summed over the commands run ({} of "
      "{} trainings finished) |\n",
      Duration(context.compute_s),
      context.models_done,
      context.models_planned);
  if (!context.trained_on.empty()) {
    md << "| trained on | "
       << MarkdownCell(fmt::format("{}", fmt::join(context.trained_on, "; ")))
       << " |\n";
  }
  md << "| report written on | " << MarkdownCell(context.machine) << " |\n";
  md << "| commit | " << context.commit << " |\n";
  md << "| date | " << context.date << " |\n\n";

  md << "**Values** are per-frame accuracy and F1 in % (REFERENCE.md 4: the "
        "mean over the frames of a take). **ours** = mean over training "
        "seeds ± sample std over seeds; **frames ±** = the std over frames "
        "(mean over seeds), the spread the paper reports; **paper** = the "
        "published mean ± std over frames.\n\n";
  md << "| variant | test | acc ours | acc frames ± | acc paper | F1 ours | "
        "F1 frames ± | F1 paper |\n";
  md << "|---|---|---|---|---|---|---|---|\n";
  for (const AblationVariant& variant : spec.variants) {
    for (const AblationTest& test : spec.tests) {
      if (!variant.Evaluates(test.name)) continue;
      md << "| " << MarkdownCell(variant.label) << " | "
         << MarkdownCell(test.label);
      for (const std::string& metric : ReproductionMetrics()) {
        const CellResult* cell =
            FindCell(cells, variant.name, test.name, metric);
        const std::optional<double> frame_std =
            cell && variant.skip.empty() ? cell->FrameStd() : std::nullopt;
        md << " | " << OursText(variant, cell) << " | "
           << (frame_std ? fmt::format("{:.2f}", *frame_std) : "") << " | "
           << PaperText(FindPaper(variant, test.name, metric));
      }
      md << " |\n";
    }
  }
  bool any_skip = false;
  for (const AblationVariant& variant : spec.variants) {
    if (variant.skip.empty()) continue;
    if (!any_skip) md << "\nSkipped rows:\n\n";
    any_skip = true;
    md << "- **" << variant.label << "**: " << variant.skip << "\n";
  }

  if (!spec.claims.empty()) {
    const std::vector<ClaimOutcome> outcomes = CheckClaims(spec, cells);
    md << "\n## The paper's claims\n\n";
    md << ClaimsSummary(outcomes)
       << ". A verdict is \"within seed noise\" when the claim's boundary "
          "(0, or ± the tolerance of a close claim) is under 2 standard "
          "errors from our gap.\n\n";
    md << "| claim | test, metric | paper gap | our gap | verdict |\n";
    md << "|---|---|---|---|---|\n";
    for (const ClaimOutcome& outcome : outcomes) {
      const AblationClaim& c = *outcome.claim;
      std::string paper = outcome.paper_gap ? Signed(*outcome.paper_gap) : "";
      if (!c.paper_note.empty()) {
        paper += (paper.empty() ? "" : " ") + ("(" + c.paper_note + ")");
      }
      const bool same_test = c.better_test == c.worse_test;
      std::string ours = outcome.gap ? Signed(*outcome.gap) : "—";
      if (outcome.gap_se) {
        ours += fmt::format(" ± {:.2f} ({}s.e.)",
                            *outcome.gap_se,
                            outcome.paired ? "paired " : "");
      }
      std::string verdict = "**" + outcome.verdict + "**";
      if (outcome.within_noise) verdict += " (within seed noise)";
      const std::string tests = same_test
                                    ? spec.Test(c.test).label
                                    : spec.Test(c.better_test).label + " vs " +
                                          spec.Test(c.worse_test).label;
      std::string text = c.text;
      if (c.origin == "ours") text += " [ours]";
      if (c.origin == "duplicate") text += " [repeated on another take]";
      md << fmt::format("| {} ({}) | {}, {} | {} | {} | {} |\n",
                        MarkdownCell(text),
                        MarkdownCell(ClaimRule(c)),
                        MarkdownCell(tests),
                        c.metric,
                        paper.empty() ? "—" : MarkdownCell(paper),
                        ours,
                        verdict);
    }
  }
  std::vector<std::string> differences;
  for (const AblationDifference& d : spec.differences) {
    if (d.AppliesTo(context.budget)) differences.push_back(d.text);
  }
  if (!differences.empty()) {
    md << "\n## Differences from the paper's setup\n\n";
    for (const std::string& d : differences) md << "- " << d << "\n";
  }
  md << "\nEvery number above comes from the runs under the reproduction's "
        "root directory (`jobs.yaml` there lists each training with its "
        "overrides, status and metrics; `commands.sh` every command); the "
        "per-seed values behind each mean and ± are in `"
     << spec.name
     << "_seeds.csv` beside this report. The "
        "paper's numbers are typed in from the paper in `ablations/"
     << spec.name << ".yaml` and appear only in the paper columns.\n";
  WriteFileAtomic(path, md.str());
}

}  // namespace soma
