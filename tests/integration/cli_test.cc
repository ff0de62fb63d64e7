// End-to-end tests of the `soma` executable: run and multirun directories,
// the resumable ledger, failures, seed aggregation, the parallel launcher and
// the one-line errors for bad input.
#include "framework/config/node.h"
#include "framework/config/yaml_io.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <chrono>
#include <fcntl.h>
#include <filesystem>
#include <regex>
#include <signal.h>
#include <sstream>
#include <string>
#include <string_view>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

struct CommandResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

std::string Quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') {
      out += "'\\''";
    } else {
      out += c;
    }
  }
  return out + "'";
}

std::string ConfigsDir() { return (testing::SourceDir() / "configs").string(); }

/// Runs a shell command in `cwd`, capturing stdout and stderr.
CommandResult RunShell(const fs::path& cwd, const std::string& command) {
  const fs::path out = cwd / "stdout.txt", err = cwd / "stderr.txt";
  const std::string line = fmt::format("cd {} && {} > {} 2> {}",
                                       Quote(cwd.string()),
                                       command,
                                       Quote(out.string()),
                                       Quote(err.string()));
  const int status = std::system(line.c_str());
  CommandResult result;
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  result.out = ReadFile(out);
  result.err = ReadFile(err);
  return result;
}

/// Runs `soma args...` in `cwd`, capturing stdout and stderr.
CommandResult RunSoma(const fs::path& cwd,
                      const std::vector<std::string>& args) {
  std::string command = Quote(SOMA_BINARY);
  for (const std::string& arg : args) {
    command += ' ';
    command += Quote(arg);
  }
  return RunShell(cwd, command);
}

ConfigNode LoadYaml(const fs::path& path) {
  return ParseYaml(ReadFile(path), path.string());
}

int CountOccurrences(const std::string& text, const std::string& needle) {
  int count = 0;
  for (size_t pos = text.find(needle); pos != std::string::npos;
       pos = text.find(needle, pos + 1)) {
    ++count;
  }
  return count;
}

int CountLines(const std::string& text) {
  int lines = 0;
  for (char c : text) lines += c == '\n';
  return lines;
}

TEST(Cli, CfgJobPrintsTheComposedDefault) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir, {"-cp", ConfigsDir(), "--cfg", "job"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const ConfigNode cfg = ParseYaml(r.out, "<stdout>");
  // The main job: label and score a real capture (README command 1).
  EXPECT_EQ(cfg.at("task").at("name").AsString(), "label_eval");
  EXPECT_EQ(cfg.Find("hydra"), nullptr);
  EXPECT_FALSE(fs::exists(dir / "results"));  // --cfg never writes
}

TEST(Cli, CfgResolvePackageSelectsASubtree) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir,
                                  {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "--cfg",
                                   "job",
                                   "--resolve",
                                   "-p",
                                   "task",
                                   "task.steps=7"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("# @package task"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("steps: 7"), std::string::npos) << r.out;
}

// Hydra 1.3: `--cfg job --resolve` prints an escaped interpolation `\${a}`
// as the literal string `${a}`; without --resolve the source form stays.
TEST(Cli, CfgResolvePrintsEscapedInterpolationsAsTheirValue) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(dir / "conf",
                         "config.yaml",
                         "a: 1\n"
                         "b: \\${a}\n"
                         "c: 'x \\${a} y'\n"
                         "d: ${b}\n");
  const std::string conf = (dir / "conf").string();
  const CommandResult resolved =
      RunSoma(dir, {"-cp", conf, "--cfg", "job", "--resolve"});
  ASSERT_EQ(resolved.exit_code, 0) << resolved.err;
  EXPECT_EQ(resolved.out, "a: 1\nb: ${a}\nc: x ${a} y\nd: ${a}\n");
  const CommandResult source = RunSoma(dir, {"-cp", conf, "--cfg", "job"});
  ASSERT_EQ(source.exit_code, 0) << source.err;
  EXPECT_EQ(source.out, "a: 1\nb: \\${a}\nc: x \\${a} y\nd: ${b}\n");
}

TEST(Cli, InfoDefaultsListsTheTaskGroup) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r =
      RunSoma(dir, {"-cp", ConfigsDir(), "--info", "defaults"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("task/label_eval"), std::string::npos) << r.out;
}

TEST(Cli, HelpListsGroupsAndFlags) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir, {"-cp", ConfigsDir(), "--help"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("task: "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("demo"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("body: "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("--multirun"), std::string::npos) << r.out;
}

TEST(Cli, RunWritesHydraDirectoryLogAndMetrics) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir,
                                  {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "hydra.run.dir=out/run1",
                                   "task.steps=5",
                                   "seed=3"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path run = dir / "out/run1";
  const ConfigNode config = LoadYaml(run / ".hydra/config.yaml");
  EXPECT_EQ(config.at("task").at("steps").AsInt(), 5);
  EXPECT_EQ(config.Find("hydra"), nullptr);
  const ConfigNode overrides = LoadYaml(run / ".hydra/overrides.yaml");
  ASSERT_TRUE(overrides.IsList());
  ASSERT_EQ(overrides.size(), 2u);  // hydra.* overrides are not task overrides
  EXPECT_EQ(overrides.at(size_t{0}).AsString(), "task.steps=5");
  const ConfigNode hydra = LoadYaml(run / ".hydra/hydra.yaml").at("hydra");
  EXPECT_EQ(hydra.at("runtime").at("choices").at("task").AsString(), "demo");
  EXPECT_EQ(hydra.at("runtime").at("output_dir").AsString(),
            fs::weakly_canonical(run).string());
  const ConfigNode& provenance = hydra.at("runtime").at("provenance");
  EXPECT_TRUE(provenance.Has("git_sha"));
  EXPECT_TRUE(provenance.Has("git_dirty"));
  EXPECT_TRUE(provenance.Has("host"));
  EXPECT_TRUE(provenance.Has("cpu"));
  EXPECT_TRUE(provenance.Has("build_commit"));
  EXPECT_TRUE(provenance.at("libraries").Has("yaml-cpp"));
  EXPECT_GT(provenance.at("wall_time_s").AsDouble(), 0.0);
  const std::string log = ReadFile(run / "soma.log");
  EXPECT_NE(log.find("][INFO] - demo: w="), std::string::npos) << log;
  const ConfigNode metrics = LoadYaml(run / "metrics.yaml");
  EXPECT_TRUE(metrics.Has("loss"));
}

TEST(Cli, SameSeedSameMetrics) {
  const auto dir = testing::CreateTestDir();
  for (const char* name : {"a", "b"}) {
    ASSERT_EQ(RunSoma(dir,
                      {"-cp",
                       ConfigsDir(),
                       "-cn",
                       "demo",
                       std::string("hydra.run.dir=") + name,
                       "seed=5"})
                  .exit_code,
              0);
  }
  EXPECT_EQ(ReadFile(dir / "a/metrics.csv"), ReadFile(dir / "b/metrics.csv"));
  ASSERT_EQ(
      RunSoma(dir,
              {"-cp", ConfigsDir(), "-cn", "demo", "hydra.run.dir=c", "seed=6"})
          .exit_code,
      0);
  EXPECT_NE(ReadFile(dir / "a/metrics.csv"), ReadFile(dir / "c/metrics.csv"));
}

TEST(Cli, CommandSelectsTheTask) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(
      dir, {"demo", "-cp", ConfigsDir(), "hydra.run.dir=out", "task.steps=2"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const ConfigNode overrides = LoadYaml(dir / "out/.hydra/overrides.yaml");
  EXPECT_EQ(overrides.at(size_t{0}).AsString(), "task=demo");
}

TEST(Cli, MultirunWritesJobsInHydraOrderAndResumes) {
  const auto dir = testing::CreateTestDir();
  const std::vector<std::string> args = {"-cp",
                                         ConfigsDir(),
                                         "-cn",
                                         "demo",
                                         "-m",
                                         "a=1,2",
                                         "b=x,y",
                                         "task.steps=3"};
  const CommandResult first = RunSoma(dir, args);
  ASSERT_EQ(first.exit_code, 0) << first.err;
  // The sweep dir is stable for the same command: results/multirun/demo-<id>.
  std::vector<fs::path> sweeps;
  for (const auto& e : fs::directory_iterator(dir / "results/multirun")) {
    sweeps.push_back(e.path());
  }
  ASSERT_EQ(sweeps.size(), 1u);
  const fs::path sweep = sweeps[0];
  EXPECT_TRUE(fs::exists(sweep / "multirun.yaml"));
  const ConfigNode multirun = LoadYaml(sweep / "multirun.yaml");
  const ConfigNode& task_overrides =
      multirun.at("hydra").at("overrides").at("task");
  EXPECT_EQ(task_overrides.at(size_t{0}).AsString(), "a=1,2");
  const std::vector<std::pair<std::string, std::string>> expected = {
      {"a=1", "b=x"}, {"a=1", "b=y"}, {"a=2", "b=x"}, {"a=2", "b=y"}};
  for (int i = 0; i < 4; ++i) {
    const ConfigNode overrides =
        LoadYaml(sweep / std::to_string(i) / ".hydra/overrides.yaml");
    EXPECT_EQ(overrides.at(size_t{0}).AsString(), expected[i].first) << i;
    EXPECT_EQ(overrides.at(size_t{1}).AsString(), expected[i].second) << i;
    EXPECT_TRUE(fs::exists(sweep / std::to_string(i) / "soma.log"));
  }
  const ConfigNode ledger = LoadYaml(sweep / "jobs.yaml");
  ASSERT_EQ(ledger.at("jobs").size(), 4u);
  for (const ConfigNode& job : ledger.at("jobs").items()) {
    EXPECT_EQ(job.at("status").AsString(), "done");
    EXPECT_EQ(job.at("attempts").AsInt(), 1);
  }
  EXPECT_TRUE(fs::exists(sweep / "summary.md"));

  const CommandResult second = RunSoma(dir, args);
  ASSERT_EQ(second.exit_code, 0) << second.err;
  EXPECT_EQ(CountOccurrences(second.err, "(done, skipped)"), 4) << second.err;
  const ConfigNode rerun_ledger = LoadYaml(sweep / "jobs.yaml");
  for (const ConfigNode& job : rerun_ledger.at("jobs").items()) {
    EXPECT_EQ(job.at("attempts").AsInt(), 1);
  }
}

TEST(Cli, KilledSweepFinishesOnlyTheRestOnRerun) {
  const auto dir = testing::CreateTestDir();
  const fs::path sweep = dir / "sweep";
  std::vector<std::string> args = {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "-m",
                                   "a=1,2,3",
                                   "task.steps=10",
                                   "task.step_ms=60",
                                   "hydra.sweep.dir=" + sweep.string()};
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::setpgid(0, 0);
    std::vector<char*> argv;
    std::string binary = SOMA_BINARY;
    argv.push_back(binary.data());
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const int devnull = ::open("/dev/null", O_WRONLY);
    ::dup2(devnull, 2);
    ::chdir(dir.c_str());
    ::execv(binary.c_str(), argv.data());
    ::_exit(127);
  }
  // Wait until job 0 is done and job 1 is running, then kill -9.
  bool killed = false;
  for (int i = 0; i < 600 && !killed; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (!fs::exists(sweep / "jobs.yaml")) continue;
    try {
      const ConfigNode jobs = LoadYaml(sweep / "jobs.yaml").at("jobs");
      if (jobs.size() >= 2 &&
          jobs.at(size_t{1}).at("status").AsString() == "running") {
        ::kill(pid, SIGKILL);
        killed = true;
      }
    } catch (const std::exception&) {
    }
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  ASSERT_TRUE(killed);
  {
    const ConfigNode jobs = LoadYaml(sweep / "jobs.yaml").at("jobs");
    EXPECT_EQ(jobs.at(size_t{0}).at("status").AsString(), "done");
    EXPECT_EQ(jobs.at(size_t{1}).at("status").AsString(), "running");
  }
  const CommandResult rerun = RunSoma(dir, args);
  ASSERT_EQ(rerun.exit_code, 0) << rerun.err;
  const ConfigNode jobs = LoadYaml(sweep / "jobs.yaml").at("jobs");
  ASSERT_EQ(jobs.size(), 3u);
  EXPECT_EQ(jobs.at(size_t{0}).at("attempts").AsInt(), 1);  // not re-run
  EXPECT_EQ(jobs.at(size_t{1}).at("attempts").AsInt(), 2);  // re-run
  EXPECT_EQ(jobs.at(size_t{2}).at("attempts").AsInt(), 1);
  for (const ConfigNode& job : jobs.items()) {
    EXPECT_EQ(job.at("status").AsString(), "done");
  }
}

TEST(Cli, FailedJobDoesNotStopTheSweep) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir,
                                  {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "-m",
                                   "task.fail_at_step=-1,2,-1",
                                   "task.steps=4",
                                   "hydra.sweep.dir=sweep"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(
      r.err.find("Error executing job with overrides: [task.fail_at_step=2, "),
      std::string::npos)
      << r.err;
  const ConfigNode jobs = LoadYaml(dir / "sweep/jobs.yaml").at("jobs");
  EXPECT_EQ(jobs.at(size_t{0}).at("status").AsString(), "done");
  EXPECT_EQ(jobs.at(size_t{1}).at("status").AsString(), "failed");
  EXPECT_EQ(jobs.at(size_t{2}).at("status").AsString(), "done");
  EXPECT_NE(ReadFile(dir / "sweep/1/soma.log").find("failing at step 2"),
            std::string::npos);
}

TEST(Cli, SeedRepeatsAreAggregated) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir,
                                  {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "-m",
                                   "task.lr=0.1,0.3",
                                   "seed=range(3)",
                                   "task.steps=5",
                                   "hydra.sweep.dir=sweep"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string csv = ReadFile(dir / "sweep/summary.csv");
  EXPECT_EQ(CountLines(csv), 3) << csv;  // header + 2 groups
  EXPECT_NE(csv.find("task.lr=0.1,3,3"), std::string::npos) << csv;
  EXPECT_NE(csv.find("loss_mean"), std::string::npos) << csv;
  EXPECT_NE(ReadFile(dir / "sweep/summary.md").find("±"), std::string::npos);
}

TEST(Cli, ParallelLauncherRunsEveryJob) {
  const auto dir = testing::CreateTestDir();
  const CommandResult r = RunSoma(dir,
                                  {"-cp",
                                   ConfigsDir(),
                                   "-cn",
                                   "demo",
                                   "-m",
                                   "seed=range(4)",
                                   "task.steps=3",
                                   "hydra.launcher.n_jobs=2",
                                   "hydra.sweep.dir=sweep"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const ConfigNode jobs = LoadYaml(dir / "sweep/jobs.yaml").at("jobs");
  ASSERT_EQ(jobs.size(), 4u);
  for (const ConfigNode& job : jobs.items()) {
    EXPECT_EQ(job.at("status").AsString(), "done");
    EXPECT_TRUE(job.at("metrics").Has("loss"));
  }
}

// ---- Bad input: one line, non-zero exit, no output directory.

struct BadInputCase {
  std::string name;
  std::vector<std::string> args;
  std::string expected;  // substring of the one-line error
};

void PrintTo(const BadInputCase& c, std::ostream* os) { *os << c.name; }

class BadInput : public ::testing::TestWithParam<BadInputCase> {};

TEST_P(BadInput, OneLineErrorNonZeroExitNoOutput) {
  const BadInputCase& c = GetParam();
  const auto dir = testing::CreateTestDir();
  // A small config tree of its own for cases that need broken files.
  testing::WriteTextFile(dir,
                         "conf/config.yaml",
                         "defaults:\n  - task: demo\n  - _self_\nx: 1\n"
                         "hydra:\n  run:\n    dir: out\n");
  testing::WriteTextFile(dir, "conf/task/demo.yaml", "name: demo\nsteps: 2\n");
  testing::WriteTextFile(dir, "conf/task/other.yaml", "name: demo\nsteps: 3\n");
  testing::WriteTextFile(dir, "conf/bad.yaml", "a: [1, 2\nb: 3\n");
  testing::WriteTextFile(
      dir, "conf/twice.yaml", "defaults:\n  - task: demo\n  - task: other\n");
  std::vector<std::string> args = {"-cp", (dir / "conf").string()};
  args.insert(args.end(), c.args.begin(), c.args.end());
  const CommandResult r = RunSoma(dir, args);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(CountLines(r.err), 1) << r.err;
  EXPECT_NE(r.err.find(c.expected), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out")) << "a failed composition wrote output";
}

INSTANTIATE_TEST_SUITE_P(
    Cli,
    BadInput,
    ::testing::Values(
        BadInputCase{"malformed_yaml", {"-cn", "bad"}, "bad.yaml:"},
        BadInputCase{"unknown_option",
                     {"task=nope"},
                     "Available options in 'task': demo, other"},
        BadInputCase{"override_missing_key", {"nokey=1"}, "+nokey=1"},
        BadInputCase{
            "append_existing_key", {"+x=2"}, "An item is already at 'x'"},
        BadInputCase{"sweep_without_m",
                     {"x=1,2"},
                     "Ambiguous value for argument 'x=1,2'"},
        BadInputCase{
            "unknown_flag", {"--frobnicate"}, "Unknown flag '--frobnicate'"},
        BadInputCase{"missing_config_dir",
                     {"-cp", "/nonexistent/conf"},
                     "/nonexistent/conf"},
        BadInputCase{
            "group_twice", {"-cn", "twice"}, "Multiple values for task"}),
    [](const ::testing::TestParamInfo<BadInputCase>& info) {
      return info.param.name;
    });

TEST(Cli, InterpolationCyclePrintsTheChain) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(
      dir,
      "conf/config.yaml",
      "defaults:\n  - task: demo\n  - _self_\ny: ${z}\nz: ${y}\n");
  testing::WriteTextFile(dir, "conf/task/demo.yaml", "name: demo\nsteps: 2\n");
  const CommandResult r =
      RunSoma(dir, {"-cp", (dir / "conf").string(), "hydra.run.dir=out"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_EQ(CountLines(r.err), 1) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out"));
  EXPECT_NE(r.err.find("y"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("z"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("cycle"), std::string::npos) << r.err;
}

TEST(Cli, MandatoryValueReadNamesTheFullKey) {
  const auto dir = testing::CreateTestDir();
  testing::WriteTextFile(
      dir, "conf/config.yaml", "defaults:\n  - task: demo\n  - _self_\n");
  testing::WriteTextFile(
      dir, "conf/task/demo.yaml", "name: demo\nsteps: ???\n");
  const CommandResult r =
      RunSoma(dir, {"-cp", (dir / "conf").string(), "hydra.run.dir=out"});
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("MissingMandatoryValue: task.steps"), std::string::npos)
      << r.err;
  // The run directory exists (the job started) but holds the error, not
  // metrics.
  EXPECT_FALSE(fs::exists(dir / "out/metrics.yaml"));
  EXPECT_TRUE(fs::exists(dir / "out/error.txt"));
}

/// The `./build/soma` command lines of the fenced code blocks of a markdown
/// file, continuation lines joined and `<placeholder>`s replaced by a word.
std::vector<std::string> DocumentedSomaCommands(const fs::path& markdown) {
  static const std::regex placeholder("<[^>]*>");
  std::vector<std::string> commands;
  std::istringstream in(ReadFile(markdown));
  bool fenced = false;
  std::string line, command;
  while (std::getline(in, line)) {
    if (line.rfind("```", 0) == 0) {
      fenced = !fenced;
      continue;
    }
    if (!fenced) continue;
    if (command.empty() && line.rfind("./build/soma ", 0) != 0) continue;
    const bool continued = !line.empty() && line.back() == '\\';
    command += continued ? line.substr(0, line.size() - 1) : line;
    if (!continued) {
      commands.push_back(std::regex_replace(command, placeholder, "x"));
      command.clear();
    }
  }
  return commands;
}

/// Runs a documented command line through bash with `./build/soma` bound to
/// `soma ... --cfg job`: it parses and composes, and runs nothing.
CommandResult ComposeDocumentedCommand(const fs::path& cwd,
                                       const std::string& line) {
  const std::string_view prefix = "./build/soma";
  const std::string script =
      fmt::format("soma() {{ {} \"$@\" -cp {} --cfg job; }}; soma{}",
                  Quote(SOMA_BINARY),
                  Quote(ConfigsDir()),
                  line.substr(prefix.size()));
  return RunShell(cwd, "bash -c " + Quote(script));
}

// Every `soma` command the README shows parses and composes as written, so
// the documentation cannot drift from the command line (a list override with
// unquoted `=` in its items once slipped into it).
TEST(Cli, EveryReadmeCommandComposes) {
  const auto dir = testing::CreateTestDir();
  const std::vector<std::string> commands =
      DocumentedSomaCommands(testing::SourceDir() / "README.md");
  EXPECT_GE(commands.size(), 30u);  // the extraction found them
  for (const std::string& line : commands) {
    const CommandResult r = ComposeDocumentedCommand(dir, line);
    EXPECT_EQ(r.exit_code, 0) << line << "\n" << r.err;
  }
  EXPECT_FALSE(fs::exists(dir / "results"));  // --cfg never writes
  // The check can fail: the slip it guards against does not compose.
  const CommandResult bad = ComposeDocumentedCommand(
      dir, "./build/soma reproduce table5 \"task.budget=[scale=cpu]\"");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.err.find("task.budget"), std::string::npos) << bad.err;
}

}  // namespace
}  // namespace soma
