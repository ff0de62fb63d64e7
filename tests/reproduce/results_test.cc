// The committed results/: no result names a build from a dirty tree, the
// claims CSVs agree with the specs on whose each claim is, and the headline
// numbers that README.md and results/README.md quote are the ones in the
// committed report CSVs (so a regenerated report cannot leave a stale quote
// behind). Reads files only; fast.
#include "framework/core/file.h"
#include "framework/reproduce/ablation_spec.h"
#include "framework/reproduce/report.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

/// One CSV line split into fields ("..." quoting with "" escapes).
std::vector<std::string> SplitCsvLine(const std::string& line) {
  std::vector<std::string> fields(1);
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        fields.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        fields.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      fields.emplace_back();
    } else {
      fields.back() += c;
    }
  }
  return fields;
}

/// The rows of a CSV file as column -> value maps.
std::vector<std::map<std::string, std::string>> ReadCsv(const fs::path& path) {
  std::istringstream in(ReadFile(path));
  std::string line;
  std::getline(in, line);
  const std::vector<std::string> header = SplitCsvLine(line);
  std::vector<std::map<std::string, std::string>> rows;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    const std::vector<std::string> fields = SplitCsvLine(line);
    EXPECT_EQ(fields.size(), header.size()) << path << ": " << line;
    std::map<std::string, std::string> row;
    for (size_t i = 0; i < header.size() && i < fields.size(); ++i) {
      row[header[i]] = fields[i];
    }
    rows.push_back(std::move(row));
  }
  return rows;
}

std::vector<fs::path> Files(const fs::path& dir, const std::string& suffix) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name.size() > suffix.size() &&
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0) {
      files.push_back(entry.path());
    }
  }
  return files;
}

const std::vector<fs::path>& ResultsDirs() {
  static const std::vector<fs::path> kDirs = {
      testing::SourceDir() / "results",
      testing::SourceDir() / "results/hdm05_layout",
      testing::SourceDir() / "results/headline_budget"};
  return kDirs;
}

/// A regex matching `value` (read from a CSV with 2 decimals) written with
/// `decimals`: both roundings where the CSV's own rounding leaves a tie
/// (6.85 may be 6.849 or 6.851, so "6.8" and "6.9" both match).
std::string Number(double value, int decimals) {
  const double step = std::pow(10.0, -decimals);
  std::vector<std::string> texts;
  for (const double v : {value - 0.0051, value, value + 0.0051}) {
    const std::string text = fmt::format("{:.{}f}", v, decimals);
    if (std::abs(std::stod(text) - value) <= step / 2 + 0.0051 &&
        std::find(texts.begin(), texts.end(), text) == texts.end()) {
      texts.push_back(text);
    }
  }
  std::string pattern = "(?:";
  for (size_t i = 0; i < texts.size(); ++i) {
    if (i > 0) pattern += '|';
    pattern += std::regex_replace(texts[i], std::regex(R"(\.)"), R"(\.)");
  }
  return pattern + ")";
}

/// A regex for "mean ± std" of one cell of a report CSV, with `decimals`.
std::string Cell(const std::string& csv,
                 const std::string& variant,
                 const std::string& test,
                 const std::string& metric = "acc",
                 int decimals = 1,
                 bool with_std = true) {
  for (const auto& row : ReadCsv(testing::SourceDir() / csv)) {
    if (row.at("variant") != variant || row.at("test") != test ||
        row.at("metric") != metric) {
      continue;
    }
    std::string text = Number(std::stod(row.at("mean")), decimals);
    if (with_std) {
      text += " ± " + Number(std::stod(row.at("std_seeds")), decimals);
    }
    return text;
  }
  ADD_FAILURE() << csv << ": no cell " << variant << "/" << test << "/"
                << metric;
  return "";
}

/// The string holds a match of the regex `pattern`: a quoted number
/// differs from its report CSV when it does not.
/// Line breaks and runs of spaces in both count as one space.
MATCHER_P(MatchesSomewhere, pattern, "has a match for /" + pattern + "/") {
  const std::regex space(R"(\s+)");
  const std::string& text = arg;
  const std::string& wanted = pattern;
  const std::regex regex(std::regex_replace(wanted, space, " "));
  return std::regex_search(std::regex_replace(text, space, " "), regex);
}

std::string Readme() { return ReadFile(testing::SourceDir() / "README.md"); }
std::string ResultsReadme() {
  return ReadFile(testing::SourceDir() / "results/README.md");
}

// Issue #23: no committed result comes from a dirty tree. Every text file
// under results/ (reports, notes, CSVs, benchmark JSONs) is searched for a
// commit named "<sha>-dirty": a report, a note quoting a run's provenance or
// a benchmark's context. Regenerate such a result from a clean tree.
TEST(ResultsTest, NoCommittedResultNamesADirtyCommit) {
  const std::regex dirty(R"([0-9a-f]{7,40}(…|\.\.\.)?-dirty)");
  const fs::path results = testing::SourceDir() / "results";
  // What git ignores under results/ (the reproductions' ledgers and runs,
  // fitted layouts), from .gitignore's "/results/<dir>" lines.
  std::vector<std::string> ignored;
  std::istringstream gitignore(ReadFile(testing::SourceDir() / ".gitignore"));
  for (std::string line; std::getline(gitignore, line);) {
    if (line.rfind("/results/", 0) != 0) continue;
    line = line.substr(9);
    if (!line.empty() && line.back() == '/') line.pop_back();
    ignored.push_back(line);
  }
  EXPECT_FALSE(ignored.empty()) << ".gitignore ignores nothing under results/";
  int files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(results)) {
    const fs::path& path = entry.path();
    const std::string ext = path.extension().string();
    if (!entry.is_regular_file() ||
        (ext != ".md" && ext != ".csv" && ext != ".json" && ext != ".yaml")) {
      continue;
    }
    const std::string relative = fs::relative(path, results).string();
    if (std::any_of(ignored.begin(), ignored.end(), [&](const std::string& d) {
          return relative.rfind(d + "/", 0) == 0;
        })) {
      continue;
    }
    ++files;
    std::istringstream lines(ReadFile(path));
    int number = 0;
    for (std::string line; std::getline(lines, line);) {
      ++number;
      std::smatch match;
      if (std::regex_search(line, match, dirty)) {
        ADD_FAILURE() << path.string() << ":" << number << " names "
                      << match.str() << ", a build from uncommitted changes";
      }
    }
  }
  EXPECT_GT(files, 50) << "results/ was not found or is nearly empty";
}

TEST(ResultsTest, ClaimsCsvsAgreeWithTheSpecsOnWhoseEachClaimIs) {
  const fs::path specs = testing::SourceDir() / "ablations";
  for (const fs::path& dir : ResultsDirs()) {
    for (const fs::path& csv : Files(dir, "_claims.csv")) {
      for (const auto& row : ReadCsv(csv)) {
        const AblationSpec spec = LoadAblationSpec(row.at("table"), specs);
        bool found = false;
        for (const AblationClaim& claim : spec.claims) {
          if (claim.text != row.at("claim")) continue;
          found = true;
          EXPECT_EQ(row.at("origin"), claim.origin)
              << csv << ": " << claim.text;
        }
        EXPECT_TRUE(found) << csv << ": '" << row.at("claim")
                           << "' is not a claim of ablations/"
                           << row.at("table") << ".yaml";
      }
    }
  }
}

/// "26 of the paper's own claims, 17 pass, 9 fail, 14 of those verdicts
/// within seed noise", counted from the claims CSVs of `dir`.
std::string OwnClaimsSentence(const fs::path& dir) {
  int claims = 0, pass = 0, fail = 0, noise = 0;
  for (const fs::path& csv : Files(dir, "_claims.csv")) {
    for (const auto& row : ReadCsv(csv)) {
      if (row.at("origin") != "paper") continue;
      ++claims;
      pass += row.at("verdict") == "pass";
      fail += row.at("verdict") == "fail";
      noise += row.at("within_noise") == "1";
    }
  }
  return fmt::format(
      "{} of the paper's own claims, {} pass, {} fail, {} of those verdicts "
      "within seed noise",
      claims,
      pass,
      fail,
      noise);
}

TEST(ResultsTest, ResultsReadmeCountsTheClaimsOfTheCommittedCsvs) {
  const std::string readme = ResultsReadme();
  for (const fs::path& dir : ResultsDirs()) {
    EXPECT_THAT(readme, HasSubstr(OwnClaimsSentence(dir))) << dir;
  }
}

TEST(ResultsTest, ReadmeQuotesTable5AsItsReportsSayIt) {
  const std::string readme = Readme();
  const std::string t5 = "results/table5.csv";
  EXPECT_THAT(readme,
              MatchesSomewhere(Cell(t5, "target_layout", "hdm05") +
                               "% on the HDM05 take\nagainst " +
                               Cell(t5, "base", "hdm05") + "% with cmu41"));
  EXPECT_THAT(readme,
              MatchesSomewhere(Cell(t5, "target_layout", "cmu") + "% against " +
                               Cell(t5, "base", "cmu") + "% on the CMU take"));
  // The same command retrained for results/hdm05_layout/.
  EXPECT_THAT(readme,
              MatchesSomewhere(
                  "gives " +
                  Cell("results/hdm05_layout/fig_c1.csv", "layers_4", "hdm05") +
                  "% on the HDM05 take"));
  const std::string results = ResultsReadme();
  EXPECT_THAT(results,
              MatchesSomewhere(Cell(t5, "target_layout", "hdm05") +
                               "% on the HDM05 take against " +
                               Cell(t5, "base", "hdm05") + "% for the base"));
  EXPECT_THAT(
      results,
      MatchesSomewhere(
          "motion library gives " +
          Cell("results/hdm05_layout/fig_c1.csv", "layers_4", "hdm05")));
}

/// The README quotes `<words><mean>%` (two decimals, no spread) for each
/// (words, variant) of `test`'s accuracy in `csv`; `words` is a regex.
void ExpectReadmeQuotesAccuracies(
    const std::string& csv,
    const std::string& test,
    const std::vector<std::pair<std::string, std::string>>& quotes) {
  const std::string readme = Readme();
  for (const auto& [words, variant] : quotes) {
    EXPECT_THAT(readme,
                MatchesSomewhere(
                    words + Cell(csv, variant, test, "acc", 2, false) + "%"))
        << csv << ": " << variant;
  }
}

// Table 5 at the headline budget on the fitted layout
// (results/headline_budget/): the README quotes each row's HDM05 accuracy as
// the report's CSV has it.
TEST(ResultsTest, ReadmeQuotesTable5AtTheHeadlineBudgetAsItsReportSaysIt) {
  ExpectReadmeQuotesAccuracies(
      "results/headline_budget/table5.csv",
      "hdm05",
      {{"base ", "base"},
       {"real-marker noise ", "real_noise"},
       {"shape variation ", "no_shape_variation"},
       {"Log-Softmax ", "log_softmax"},
       {"random marker placement ", "no_marker_placement"},
       {"transformer ", "no_transformer"}});
}

// Table 1 at the same budget: the B+C+G test column (SOMA's protocol), one
// training noise per row.
TEST(ResultsTest, ReadmeQuotesTable1AtTheHeadlineBudgetAsItsReportSaysIt) {
  ExpectReadmeQuotesAccuracies("results/headline_budget/table1.csv",
                               "b_c_g",
                               {{"train B ", "train_b"},
                                {"train B\\+C ", "train_b_c"},
                                {"train B\\+G ", "train_b_g"},
                                {"train B\\+C\\+G ", "train_b_c_g"}});
}

// Fig. C.3 at the same budget: each row's accuracy on the HDM05 take as
// B+C+G.
TEST(ResultsTest, ReadmeQuotesFigC3AtTheHeadlineBudgetAsItsReportSaysIt) {
  ExpectReadmeQuotesAccuracies(
      "results/headline_budget/fig_c3.csv",
      "hdm05",
      {{"B\\+C\\+G, base ", "base"},
       {"spherical-Gaussian ghosts ", "ghosts60_gaussian"},
       {"uniform ghosts ", "ghosts60_uniform"},
       {"skewed-Gaussian ghosts ", "ghosts60_skewed"}});
}

/// The README quotes `**<mean>%**` (two decimals, bold) for each (variant,
/// test) accuracy of `csv`.
void ExpectReadmeQuotesBoldAccuracies(
    const std::string& csv,
    const std::vector<std::pair<std::string, std::string>>& cells) {
  const std::string readme = Readme();
  for (const auto& [variant, test] : cells) {
    EXPECT_THAT(
        readme,
        MatchesSomewhere("\\*\\*" + Cell(csv, variant, test, "acc", 2, false) +
                         "%\\*\\*"))
        << csv << ": " << variant << " on " << test;
  }
}

using CsvRow = std::map<std::string, std::string>;

/// The README quotes each claim of `claims_csv` (relative to the source
/// directory) that `select` picks as "|gap| ± s.e.", two decimals. Returns
/// how many claims it checked.
template <typename Select>
int ExpectReadmeQuotesClaimGaps(const std::string& claims_csv,
                                const Select& select) {
  const std::string readme = Readme();
  int checked = 0;
  for (const CsvRow& row : ReadCsv(testing::SourceDir() / claims_csv)) {
    if (!select(row)) continue;
    ++checked;
    EXPECT_THAT(
        readme,
        MatchesSomewhere(Number(std::abs(std::stod(row.at("gap"))), 2) +
                         "\\s+±\\s+" + Number(std::stod(row.at("gap_se")), 2)))
        << claims_csv << ": " << row.at("claim");
  }
  return checked;
}

/// The (variant, test) cells of every variant on each of the any_layout
/// spec's three takes.
std::vector<std::pair<std::string, std::string>> OnEveryAnyLayoutTake(
    const std::vector<std::string>& variants) {
  std::vector<std::pair<std::string, std::string>> cells;
  for (const std::string& variant : variants) {
    for (const std::string test : {"hdm05", "cmu", "pig"}) {
      cells.emplace_back(variant, test);
    }
  }
  return cells;
}

// The perturbed-layout variants (results/any_layout_perturbed/), with and
// without Fourier features and at 60 epochs: the README quotes each on each
// take, bold.
TEST(ResultsTest, ReadmeQuotesThePerturbedLayoutRunAsItsReportSaysIt) {
  ExpectReadmeQuotesBoldAccuracies(
      "results/any_layout_perturbed/any_layout.csv",
      OnEveryAnyLayoutTake({"any_layout_perturbed_only",
                            "any_layout_perturbed",
                            "any_layout_perturbed_fourier",
                            "any_layout_perturbed_fourier_60"}));
}

// The conditioned model and the per-layout models at the same 60 epochs
// (results/any_layout_equal/): the README quotes each on its takes, bold.
TEST(ResultsTest, ReadmeQuotesTheEqualEpochsRunAsItsReportSaysIt) {
  ExpectReadmeQuotesBoldAccuracies(
      "results/any_layout_equal/any_layout.csv",
      {{"any_layout_perturbed_fourier_60", "hdm05"},
       {"any_layout_perturbed_fourier_60", "cmu"},
       {"any_layout_perturbed_fourier_60", "pig"},
       {"hdm05_layout_60", "hdm05"},
       {"cmu41_layout_60", "cmu"},
       {"pig_layout_60", "pig"}});
}

// The perturbations that reach farther (results/any_layout_wide/): the
// README quotes each new variant on each take, and the per-layout HDM05
// model over its 2 seeds, bold.
TEST(ResultsTest, ReadmeQuotesTheWiderPerturbationRunAsItsReportSaysIt) {
  auto cells = OnEveryAnyLayoutTake({"any_layout_perturbed6_fourier_60",
                                     "any_layout_perturbed8r_fourier_60",
                                     "any_layout_perturbed700_fourier_60"});
  cells.emplace_back("hdm05_layout_60", "hdm05");
  ExpectReadmeQuotesBoldAccuracies("results/any_layout_wide/any_layout.csv",
                                   cells);
}

/// A fine-tuning table (ablations/any_layout_finetune.sh): per target, the
/// mean accuracy in % over its seeds at each epoch count, in epoch order, as
/// Number regexes with 2 decimals.
std::map<std::string, std::vector<std::string>> FinetuneMeans(
    const std::string& csv) {
  std::map<std::string, std::map<int, std::vector<double>>> tuned;
  for (const auto& row : ReadCsv(testing::SourceDir() / csv)) {
    tuned[row.at("target")][std::stoi(row.at("epochs"))].push_back(
        100 * std::stod(row.at("acc_mean")));
  }
  std::map<std::string, std::vector<std::string>> means;
  for (const auto& [target, by_epochs] : tuned) {
    for (const auto& [epochs, values] : by_epochs) {
      double sum = 0;
      for (const double v : values) sum += v;
      means[target].push_back(
          Number(sum / static_cast<double>(values.size()), 2));
    }
  }
  return means;
}

// Issue #25 item 3: the README's any-layout paragraph quotes the report
// (conditioned and per-layout models, bold) and the fine-tuning table (the
// mean over its seeds per target and epoch count, in epoch order).
TEST(ResultsTest, ReadmeQuotesTheAnyLayoutRunAsItsReportsSayIt) {
  ExpectReadmeQuotesBoldAccuracies("results/any_layout.csv",
                                   {{"any_layout", "hdm05"},
                                    {"any_layout", "cmu"},
                                    {"any_layout", "pig"},
                                    {"hdm05_layout", "hdm05"},
                                    {"cmu41_layout", "cmu"},
                                    {"pig_layout", "pig"}});
  const std::string readme = Readme();
  const auto tuned = FinetuneMeans("results/any_layout_finetune.csv");
  ASSERT_EQ(tuned.size(), 2u);
  for (const auto& [target, means] : tuned) {
    ASSERT_EQ(means.size(), 3u) << target;
    // "87.47% after 1 epoch (13 s of training), 89.50% after 2 and 90.60%"
    // (HDM05); "87.04, 84.31 and 90.18%" (Plug-in Gait).
    const std::string pattern =
        target == "hdm05"
            ? means[0] + "%\\s+after\\s+1\\s+epoch[^,]*,\\s+" + means[1] +
                  "%?\\s+after\\s+2\\s+and\\s+" + means[2] + "%"
            : means[0] + ",\\s+" + means[1] + "\\s+and\\s+" + means[2] + "%";
    EXPECT_THAT(readme, MatchesSomewhere(pattern)) << target;
  }
}

// The learning levers (results/any_layout_learning/): the README quotes
// each conditioned variant on each take and the per-layout HDM05 models,
// bold; and the fine-tuning of the ring-draw model at lr 1e-3 and 1e-4 as
// "a, b and c%" (1, 2 and 4 epochs) per target.
TEST(ResultsTest, ReadmeQuotesTheLearningRunAsItsReportSaysIt) {
  auto cells = OnEveryAnyLayoutTake({"any_layout_perturbed8r_fourier_60_cosine",
                                     "any_layout_perturbed8r_fourier8_60",
                                     "any_layout_perturbed8r_fourier_deep_60"});
  cells.insert(cells.end(),
               {{"hdm05_layout_60_cosine", "hdm05"},
                {"cmu41_layout_60", "cmu"},
                {"pig_layout_60", "pig"}});
  ExpectReadmeQuotesBoldAccuracies("results/any_layout_learning/any_layout.csv",
                                   cells);
  const std::string readme = Readme();
  for (const std::string csv :
       {"results/any_layout_learning/finetune_lr1e-3.csv",
        "results/any_layout_learning/finetune_lr1e-4.csv"}) {
    const auto tuned = FinetuneMeans(csv);
    ASSERT_EQ(tuned.size(), 2u) << csv;
    for (const auto& [target, means] : tuned) {
      ASSERT_EQ(means.size(), 3u) << csv << ": " << target;
      EXPECT_THAT(readme,
                  MatchesSomewhere(means[0] + ",\\s+" + means[1] +
                                   "\\s+and\\s+" + means[2] + "%"))
          << csv << ": " << target;
    }
  }
}

// The recipe levers (results/any_layout_recipe/): the README quotes each
// variant on each take, bold.
TEST(ResultsTest, ReadmeQuotesTheRecipeRunAsItsReportSaysIt) {
  ExpectReadmeQuotesBoldAccuracies(
      "results/any_layout_recipe/any_layout.csv",
      OnEveryAnyLayoutTake({"any_layout_perturbed8r_fourier_b32_60",
                            "any_layout_perturbed8r_fourier_share80_60",
                            "any_layout_perturbed8r_fourier_pos10_60",
                            "any_layout_perturbed8r_fourier_cross2_60"}));
}

// The larger rates and the weight average (results/any_layout_average/):
// the README quotes each new variant on each take, and the per-layout HDM05
// model with the average, bold.
TEST(ResultsTest, ReadmeQuotesTheWeightAverageRunAsItsReportSaysIt) {
  auto cells =
      OnEveryAnyLayoutTake({"any_layout_perturbed8r_fourier_lr2e3_60",
                            "any_layout_perturbed8r_fourier_lr3e3cos_60",
                            "any_layout_perturbed8r_fourier_ema_60"});
  cells.emplace_back("hdm05_layout_60_ema", "hdm05");
  ExpectReadmeQuotesBoldAccuracies("results/any_layout_average/any_layout.csv",
                                   cells);
}

// Fine-tuning the averaged conditioned model (results/any_layout_finetune/):
// the README quotes the report's models bold, the two from-scratch variants
// as "a, b and c%", and each fine-tuning table's means over seeds per epoch
// count, in epoch order, in the phrasing of its sentence.
TEST(ResultsTest, ReadmeQuotesTheFineTuningOfTheAverageAsItsTablesSayIt) {
  const std::string dir = "results/any_layout_finetune/";
  const std::string csv = dir + "any_layout.csv";
  ExpectReadmeQuotesBoldAccuracies(
      csv,
      {{"any_layout_perturbed8r_fourier_ema_60", "hdm05"},
       {"hdm05_layout_60", "hdm05"},
       {"hdm05_layout_60_ema", "hdm05"}});
  const std::string readme = Readme();
  for (const std::string variant :
       {"any_layout_perturbed8r_fourier_ema9997_60",
        "any_layout_perturbed8r_fourier_share80_ema_60"}) {
    EXPECT_THAT(readme,
                MatchesSomewhere(
                    Cell(csv, variant, "hdm05", "acc", 2, false) + ",\\s+" +
                    Cell(csv, variant, "cmu", "acc", 2, false) + "\\s+and\\s+" +
                    Cell(csv, variant, "pig", "acc", 2, false) + "%"))
        << variant;
  }
  const std::string sep = "\\s+/\\s+";
  // "**92.51%** to 94.09, 94.43, 94.82, 95.07 and **95.22%**" (0 to 16
  // epochs); "95.81% before, 95.80 / 95.73 / 95.88 / 95.24 / 94.83%".
  const auto slow = FinetuneMeans(dir + "finetune_lr1e-4_ema.csv");
  ASSERT_EQ(slow.size(), 2u);
  const std::vector<std::string>& h = slow.at("hdm05");
  ASSERT_EQ(h.size(), 6u);
  EXPECT_THAT(readme,
              MatchesSomewhere("\\*\\*" + h[0] + "%\\*\\*\\s+to\\s+" + h[1] +
                               ",\\s+" + h[2] + ",\\s+" + h[3] + ",\\s+" +
                               h[4] + "\\s+and\\s+\\*\\*" + h[5] + "%\\*\\*"));
  const std::vector<std::string>& p = slow.at("pig");
  ASSERT_EQ(p.size(), 6u);
  EXPECT_THAT(readme,
              MatchesSomewhere(p[0] + "%\\s+before,\\s+" + p[1] + sep + p[2] +
                               sep + p[3] + sep + p[4] + sep + p[5] + "%"));
  // "95.01 and 95.57% after 4 and 16 epochs and **96.03%** after 32", "60
  // epochs of fine-tuning reach **96.22%**"; "95.87 and 94.61% after 4 and
  // 16".
  const auto fast = FinetuneMeans(dir + "finetune_lr3e-4cos_ema.csv");
  ASSERT_EQ(fast.at("hdm05").size(), 5u);
  EXPECT_THAT(readme,
              MatchesSomewhere("60\\s+epochs\\s+of\\s+fine-tuning\\s+reach\\s+"
                               "\\*\\*" +
                               fast.at("hdm05")[4] + "%\\*\\*"));
  EXPECT_THAT(readme,
              MatchesSomewhere(
                  fast.at("hdm05")[1] + "\\s+and\\s+" + fast.at("hdm05")[2] +
                  "%\\s+after\\s+4\\s+and\\s+16\\s+epochs\\s+and\\s+"
                  "\\*\\*" +
                  fast.at("hdm05")[3] + "%\\*\\*"));
  const auto pig = FinetuneMeans(dir + "finetune_lr3e-4cos_ema_pig.csv");
  ASSERT_EQ(pig.at("pig").size(), 3u);
  EXPECT_THAT(
      readme,
      MatchesSomewhere(pig.at("pig")[1] + "\\s+and\\s+" + pig.at("pig")[2] +
                       "%\\s+after\\s+4\\s+and\\s+16"));
}

// The matching decode (results/any_layout_matching/): the README quotes, bold,
// the averaged conditioned model and the per-layout models on each take with
// the matching decode (and on HDM05 with SOMA's rule), and the HDM05 gaps of
// item 3's two matching claims as "gap ± s.e.".
TEST(ResultsTest, ReadmeQuotesTheMatchingDecodeAsItsReportSaysIt) {
  const std::string dir = "results/any_layout_matching/";
  const std::string csv = dir + "any_layout.csv";
  const std::string conditioned = "any_layout_perturbed8r_fourier_ema_60";
  ExpectReadmeQuotesBoldAccuracies(csv,
                                   {{conditioned, "hdm05"},
                                    {"hdm05_layout_60", "hdm05"},
                                    {conditioned, "hdm05_matching"},
                                    {"hdm05_layout_60", "hdm05_matching"},
                                    {"hdm05_layout_60_ema", "hdm05_matching"},
                                    {conditioned, "cmu_matching"},
                                    {"cmu41_layout_60", "cmu_matching"},
                                    {conditioned, "pig_matching"},
                                    {"pig_layout_60", "pig_matching"}});
  const int gaps = ExpectReadmeQuotesClaimGaps(
      dir + "any_layout_claims.csv", [](const CsvRow& row) {
        return row.at("better_test") == "hdm05_matching" &&
               row.at("kind") == "not_behind";
      });
  EXPECT_EQ(gaps, 2) << "item 3's HDM05 claims with the matching decode";
}

// The rest-offset logit biases (results/any_layout_relative/): the README
// quotes the biased model on each take (HDM05 with both decodes) and its
// HDM05 gap to the averaged per-layout model, both decodes matching.
TEST(ResultsTest, ReadmeQuotesTheRestOffsetBiasAsItsReportSaysIt) {
  const std::string dir = "results/any_layout_relative/";
  const std::string relative = "any_layout_perturbed8r_fourier_rel_ema_60";
  ExpectReadmeQuotesBoldAccuracies(dir + "any_layout.csv",
                                   {{relative, "hdm05"},
                                    {relative, "hdm05_matching"},
                                    {relative, "cmu_matching"},
                                    {relative, "pig_matching"}});
  const int gaps = ExpectReadmeQuotesClaimGaps(
      dir + "any_layout_claims.csv", [&](const CsvRow& row) {
        return (row.at("better") == relative || row.at("worse") == relative) &&
               row.at("better_test") == "hdm05_matching";
      });
  EXPECT_EQ(gaps, 2) << "the biased model's two HDM05 claims";
}

// Twice the epochs and eight rotated views (results/any_layout_views/): the
// README quotes the 120-epoch conditioned model on each take and both
// models with eight views on HDM05, and the gaps of item 3's claims for
// them.
TEST(ResultsTest, ReadmeQuotesTheLongerTrainingAndTheViewsAsTheirReportSays) {
  const std::string dir = "results/any_layout_views/";
  const std::string longer = "any_layout_perturbed8r_fourier_ema_120";
  const std::string averaged = "any_layout_perturbed8r_fourier_ema_60";
  ExpectReadmeQuotesBoldAccuracies(dir + "any_layout.csv",
                                   {{longer, "hdm05_matching"},
                                    {longer, "cmu_matching"},
                                    {longer, "pig_matching"},
                                    {averaged, "hdm05_views8"},
                                    {"hdm05_layout_60_ema", "hdm05_views8"}});
  const int gaps = ExpectReadmeQuotesClaimGaps(
      dir + "any_layout_claims.csv", [&](const CsvRow& row) {
        return row.at("kind") == "not_behind" &&
               (row.at("worse") == longer ||
                row.at("better_test") == "hdm05_views8");
      });
  EXPECT_EQ(gaps, 4) << "the 120-epoch model's three item-3 claims and the "
                        "eight-view HDM05 claim";
}

TEST(ResultsTest, ResultsReadmeQuotesTheFiguresAsTheirReportsSayThem) {
  const std::string readme = ResultsReadme();
  for (const std::string dir :
       {"results/", "results/hdm05_layout/", "results/headline_budget/"}) {
    const std::string c1 = dir + "fig_c1.csv";
    EXPECT_THAT(
        readme,
        MatchesSomewhere(Cell(c1, "layers_1", "hdm05") + "% with 1 layer,\n" +
                         Cell(c1, "layers_2", "hdm05") + "% with 2, " +
                         Cell(c1, "layers_4", "hdm05") + "% with 4"))
        << c1;
    EXPECT_THAT(readme,
                MatchesSomewhere(Cell(c1, "layers_8", "hdm05") + "% with 8"))
        << c1;
  }
  const std::string c2 = "results/fig_c2.csv";
  EXPECT_THAT(readme,
              MatchesSomewhere(Cell(c2, "iters_1", "hdm05") + ", " +
                               Cell(c2, "iters_5", "hdm05") + ",\n" +
                               Cell(c2, "iters_15", "hdm05") + " and " +
                               Cell(c2, "iters_35", "hdm05") + "%"));
  const std::string t2 = "results/table2.csv";
  EXPECT_THAT(readme,
              MatchesSomewhere(
                  "from " + Cell(t2, "base", "occ0", "acc", 1, false) +
                  "% at 0 occluded markers to " +
                  Cell(t2, "base", "occ5", "acc", 1, false) + "% at 5 and " +
                  Cell(t2, "base", "occ5_g", "acc", 1, false) + "%"));
  const std::string t3 = "results/table3.csv";
  EXPECT_THAT(
      readme,
      MatchesSomewhere(
          "lifts HDM05 from " +
          Cell(t3, "base", "hdm05_frame", "acc", 1, false) + "% to " +
          Cell(t3, "base", "hdm05_tracklet", "acc", 1, false) +
          "% and CMU from " + Cell(t3, "base", "cmu_frame", "acc", 1, false) +
          "% to " + Cell(t3, "base", "cmu_tracklet", "acc", 1, false)));
}

TEST(ResultsTest, ReadmeQuotesTheRealMarkerRunAsItsCsvSaysIt) {
  std::map<std::string, std::string> acc;  // take/mode -> "mean ± std"
  for (const auto& row :
       ReadCsv(testing::SourceDir() / "results/real_markers_cpu.csv")) {
    if (row.at("setting") != "OC_05_G_03_BT_00") continue;
    acc[row.at("take") + "/" + row.at("mode")] =
        Number(100 * std::stod(row.at("acc_mean")), 1) + " ± " +
        Number(100 * std::stod(row.at("acc_std")), 1);
  }
  EXPECT_THAT(
      Readme(),
      MatchesSomewhere("HDM05 " + acc["HDM_mm_01-02_03_120/per-frame"] +
                       "% per frame, " + acc["HDM_mm_01-02_03_120/tracklet"] +
                       "% in\ntracklet mode; CMU 01_01 " +
                       acc["cmu_01_01/per-frame"] + "% per frame"));
}

TEST(ResultsTest, ReadmesQuoteTheHeadlineAsItsReportSaysIt) {
  const std::string h = "results/headline.csv";
  const std::string quote = Cell(h, "hdm05_layout", "hdm05", "acc", 2) +
                            "% per frame on the real HDM05 take";
  const std::string cmu =
      Cell(h, "cmu41", "cmu", "acc", 2) + "% on the real CMU take";
  EXPECT_THAT(Readme(), MatchesSomewhere(quote));
  EXPECT_THAT(Readme(), MatchesSomewhere(cmu));
  EXPECT_THAT(ResultsReadme(), MatchesSomewhere(quote));
  EXPECT_THAT(ResultsReadme(), MatchesSomewhere(cmu));
}

}  // namespace
}  // namespace soma
