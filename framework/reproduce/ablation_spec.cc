#include "framework/reproduce/ablation_spec.h"

#include "framework/config/decode.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <set>

namespace soma {
namespace {

namespace fs = std::filesystem;

bool IsIdentifier(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
}

bool IsMetric(const std::string& metric) {
  const auto& metrics = ReproductionMetrics();
  return std::find(metrics.begin(), metrics.end(), metric) != metrics.end();
}

/// `{acc: 95.5, acc_std: 5.33, f1: 94.66, f1_std: 6.03}`.
std::map<std::string, PaperValue> ParsePaperCell(const ConfigNode& node) {
  ConfigReader reader(node);
  std::map<std::string, PaperValue> cell;
  for (const std::string& metric : ReproductionMetrics()) {
    if (const ConfigNode* mean = reader.Child(metric)) {
      PaperValue value;
      value.mean = mean->AsDouble();
      if (const ConfigNode* std = reader.Child(metric + "_std")) {
        value.std = std->AsDouble();
      }
      cell[metric] = value;
    } else {
      reader.Check(metric + "_std",
                   node.Find(metric + "_std") == nullptr,
                   fmt::format("{}_std needs {}", metric, metric));
    }
  }
  reader.Finish();
  return cell;
}

AblationVariant ParseVariant(const ConfigNode& node,
                             const std::set<std::string>& tests) {
  ConfigReader reader(node);
  AblationVariant v;
  reader.Require("name", &v.name);
  reader.Check("name", IsIdentifier(v.name), "an identifier [a-z0-9_]+");
  v.label = v.name;
  reader.Read("label", &v.label);
  reader.Read("overrides", &v.overrides);
  reader.Read("skip", &v.skip);
  reader.Read("skip_if_budget_sets", &v.skip_if_budget_sets);
  reader.Read("tests", &v.tests);
  for (const std::string& test : v.tests) {
    reader.Check("tests", tests.count(test) > 0, "names of tests of this spec");
  }
  if (const ConfigNode* paper = reader.Child("paper");
      paper != nullptr && !paper->IsNull()) {
    ConfigReader paper_reader(*paper);
    for (const auto& [test, cell] : paper->entries()) {
      paper_reader.Check(test, tests.count(test) > 0, "a test of this spec");
      paper_reader.Check(
          test, v.Evaluates(test), "a test this variant is evaluated on");
      paper_reader.Ignore(test);
      v.paper[test] = ParsePaperCell(cell);
    }
    paper_reader.Finish();
  }
  reader.Finish();
  return v;
}

AblationTest ParseTest(const std::string& name, const ConfigNode& node) {
  ConfigReader reader(node);
  AblationTest t;
  t.name = name;
  t.label = name;
  reader.Read("label", &t.label);
  reader.Require("take", &t.take);
  reader.Require("setting", &t.setting);
  reader.Read("tracklet", &t.tracklet);
  reader.Read("corrupt_overrides", &t.corrupt_overrides);
  reader.Read("eval_overrides", &t.eval_overrides);
  reader.Read("label_overrides", &t.label_overrides);
  reader.Finish();
  return t;
}

/// A string (always printed) or a map {text, if_budget_sets,
/// unless_budget_sets}.
AblationDifference ParseDifference(const ConfigNode& node) {
  AblationDifference d;
  if (node.IsScalar()) {
    d.text = node.AsString();
    return d;
  }
  ConfigReader reader(node);
  reader.Require("text", &d.text);
  reader.Read("if_budget_sets", &d.if_budget_sets);
  reader.Read("unless_budget_sets", &d.unless_budget_sets);
  reader.Check("unless_budget_sets",
               d.if_budget_sets.empty() || d.unless_budget_sets.empty(),
               "at most one of if_budget_sets and unless_budget_sets");
  reader.Finish();
  return d;
}

/// `budget` has an override `<key>=...` or `<key>.<sub>=...`.
bool BudgetSets(const std::vector<std::string>& budget,
                const std::string& key) {
  return std::any_of(budget.begin(), budget.end(), [&](const std::string& o) {
    return o.size() > key.size() && o.compare(0, key.size(), key) == 0 &&
           (o[key.size()] == '=' || o[key.size()] == '.');
  });
}

AblationClaim ParseClaim(const ConfigNode& node,
                         const std::set<std::string>& variants,
                         const std::set<std::string>& tests) {
  ConfigReader reader(node);
  AblationClaim c;
  reader.Require("text", &c.text);
  reader.Require("test", &c.test);
  reader.Check("test", tests.count(c.test) > 0, "a test of this spec");
  c.better_test = c.worse_test = c.test;
  reader.Read("better_test", &c.better_test);
  reader.Check(
      "better_test", tests.count(c.better_test) > 0, "a test of this spec");
  reader.Read("worse_test", &c.worse_test);
  reader.Check(
      "worse_test", tests.count(c.worse_test) > 0, "a test of this spec");
  reader.Read("metric", &c.metric);
  reader.Check("metric", IsMetric(c.metric), "acc or f1");
  reader.Read("kind", &c.kind);
  reader.Check(
      "kind",
      c.kind == "greater" || c.kind == "close" || c.kind == "not_behind",
      "greater, close or not_behind");
  reader.Require("better", &c.better);
  reader.Check("better", variants.count(c.better) > 0, "a variant name");
  reader.Require("worse", &c.worse);
  reader.Check("worse", variants.count(c.worse) > 0, "a variant name");
  reader.Read("tolerance", &c.tolerance);
  reader.Check("tolerance",
               c.kind == "greater" || c.tolerance > 0,
               "kind close or not_behind needs a tolerance > 0 (points)");
  if (const ConfigNode* gap = reader.Child("paper_gap");
      gap != nullptr && !gap->IsNull()) {
    c.paper_gap = gap->AsDouble();
  }
  reader.Read("paper_note", &c.paper_note);
  reader.Read("origin", &c.origin);
  reader.Check(
      "origin",
      c.origin == "paper" || c.origin == "ours" || c.origin == "duplicate",
      "paper, ours or duplicate");
  reader.Finish();
  return c;
}

}  // namespace

bool AblationVariant::Evaluates(const std::string& test) const {
  return tests.empty() ||
         std::find(tests.begin(), tests.end(), test) != tests.end();
}

const AblationVariant& AblationSpec::Variant(const std::string& v) const {
  for (const AblationVariant& variant : variants) {
    if (variant.name == v) return variant;
  }
  throw InternalError(fmt::format("ablation {}: no variant '{}'", name, v));
}

const AblationTest& AblationSpec::Test(const std::string& t) const {
  for (const AblationTest& test : tests) {
    if (test.name == t) return test;
  }
  throw InternalError(fmt::format("ablation {}: no test '{}'", name, t));
}

AblationSpec ApplyBudget(AblationSpec spec,
                         const std::vector<std::string>& budget) {
  for (AblationVariant& v : spec.variants) {
    if (v.skip.empty() && !v.skip_if_budget_sets.empty() &&
        BudgetSets(budget, v.skip_if_budget_sets)) {
      v.skip = fmt::format(
          "not trained: task.budget sets `{}` for every row, which this row "
          "varies",
          v.skip_if_budget_sets);
    }
  }
  return spec;
}

bool AblationDifference::AppliesTo(
    const std::vector<std::string>& budget) const {
  if (!if_budget_sets.empty()) return BudgetSets(budget, if_budget_sets);
  if (!unless_budget_sets.empty()) {
    return !BudgetSets(budget, unless_budget_sets);
  }
  return true;
}

AblationSpec ParseAblationSpec(const ConfigNode& node,
                               const std::string& source) {
  if (!node.IsMap()) {
    throw ConfigError(
        fmt::format("{}: an ablation spec must be a YAML map", source));
  }
  ConfigReader reader(node);
  AblationSpec spec;
  reader.Require("name", &spec.name);
  reader.Check("name", IsIdentifier(spec.name), "an identifier [a-z0-9_]+");
  reader.Require("title", &spec.title);
  reader.Read("paper_ref", &spec.paper_ref);
  reader.Read("description", &spec.description);
  reader.Read("seeds", &spec.seeds);
  reader.Check("seeds", spec.seeds >= 1, "seeds >= 1");
  if (const ConfigNode* differences = reader.Child("differences");
      differences != nullptr && !differences->IsNull()) {
    reader.Check("differences",
                 differences->IsList(),
                 "a list of strings or {text, if_budget_sets | "
                 "unless_budget_sets} maps");
    for (const ConfigNode& d : differences->items()) {
      spec.differences.push_back(ParseDifference(d));
    }
  }

  std::set<std::string> test_names;
  const ConfigNode* tests = reader.Child("tests");
  reader.Check("tests",
               tests != nullptr && tests->IsMap() && tests->size() > 0,
               "a non-empty map: test name -> {take, setting, tracklet}");
  for (const auto& [name, test] : tests->entries()) {
    if (!IsIdentifier(name)) {
      throw ConfigError(fmt::format(
          "Invalid configuration. {}: test name '{}' is not an identifier "
          "[a-z0-9_]+",
          source,
          name));
    }
    spec.tests.push_back(ParseTest(name, test));
    test_names.insert(name);
  }

  std::set<std::string> variant_names;
  const ConfigNode* variants = reader.Child("variants");
  reader.Check("variants",
               variants != nullptr && variants->IsList() && variants->size(),
               "a non-empty list of {name, label, overrides, paper}");
  for (const ConfigNode& variant : variants->items()) {
    spec.variants.push_back(ParseVariant(variant, test_names));
    if (!variant_names.insert(spec.variants.back().name).second) {
      throw ConfigError(
          fmt::format("Invalid configuration. {}: variant '{}' is defined "
                      "twice",
                      source,
                      spec.variants.back().name));
    }
  }

  if (const ConfigNode* claims = reader.Child("claims");
      claims != nullptr && !claims->IsNull()) {
    reader.Check("claims", claims->IsList(), "a list of claims");
    for (const ConfigNode& claim : claims->items()) {
      spec.claims.push_back(ParseClaim(claim, variant_names, test_names));
      const AblationClaim& c = spec.claims.back();
      for (const auto& [variant, test] :
           {std::pair{c.better, c.better_test}, {c.worse, c.worse_test}}) {
        if (!spec.Variant(variant).Evaluates(test)) {
          throw ConfigError(fmt::format(
              "Invalid configuration. {}: claim '{}' reads variant '{}' on "
              "test '{}', which that variant's tests leave out",
              source,
              c.text,
              variant,
              test));
        }
      }
    }
  }
  reader.Finish();
  return spec;
}

std::vector<std::string> ListAblationSpecs(const fs::path& dir) {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (entry.path().extension() == ".yaml") {
      names.push_back(entry.path().stem().string());
    }
  }
  std::sort(names.begin(), names.end());
  return names;
}

AblationSpec LoadAblationSpec(const std::string& name, const fs::path& dir) {
  fs::path path = name;
  if (path.extension() != ".yaml") path = dir / (name + ".yaml");
  if (!fs::is_regular_file(path)) {
    throw IoError(fmt::format("{}: no such ablation spec. Available in {}: {}",
                              path.string(),
                              dir.string(),
                              fmt::join(ListAblationSpecs(dir), ", ")));
  }
  const ConfigNode node = ParseYaml(ReadFile(path), path.string());
  AblationSpec spec = ParseAblationSpec(node, path.string());
  if (path.stem().string() != spec.name) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {}: name '{}' differs from the file name '{}'",
        path.string(),
        spec.name,
        path.stem().string()));
  }
  return spec;
}

}  // namespace soma
