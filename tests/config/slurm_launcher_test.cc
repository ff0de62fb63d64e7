// The SLURM launcher without SLURM: option decoding, the generated sbatch
// script (and its bash wrapper, run with bash), and submission errors. The
// same launcher against a real SLURM: tests/integration/slurm_test.sh.
#include "framework/config/slurm_launcher.h"

#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/config/override.h"
#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <sys/wait.h>
#include <vector>

namespace soma {
namespace {

namespace fs = std::filesystem;

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

/// The resolved `hydra.launcher` of configs/demo.yaml with `overrides`.
ConfigNode DemoLauncher(std::vector<std::string> overrides) {
  ComposeRequest request;
  request.search_path = {(testing::SourceDir() / "configs").string()};
  request.config_name = "demo";
  for (const std::string& o : overrides) {
    request.overrides.push_back(ParseOverride(o));
  }
  // Only the launcher is resolved: the rest of demo.yaml uses
  // ${soma.sweep_id:}, a resolver of the framework (not linked here).
  return Select(Compose(request).root, "hydra.launcher", DefaultResolvers());
}

SbatchScriptSpec Spec(const fs::path& sweep_dir, const std::string& exe) {
  SbatchScriptSpec spec;
  spec.job_name = "soma";
  spec.sweep_dir = sweep_dir;
  spec.workdir = sweep_dir;
  spec.executable = exe;
  spec.base_args = {"-m", "-cn", "demo"};
  spec.tasks = {{1, sweep_dir / "1", {"a=1", "b=it's"}},
                {3, sweep_dir / "3", {"a=3", "b=x y"}}};
  return spec;
}

TEST(SlurmLauncher, ArrayIndexListCompressesRuns) {
  EXPECT_EQ(ArrayIndexList({0, 1, 2, 3}), "0-3");
  EXPECT_EQ(ArrayIndexList({1, 3, 5, 6, 7}), "1,3,5-7");
  EXPECT_EQ(ArrayIndexList({2}), "2");
}

TEST(SlurmLauncher, ShellQuoteEscapesSingleQuotes) {
  EXPECT_EQ(ShellQuote("a b"), "'a b'");
  EXPECT_EQ(ShellQuote("it's"), "'it'\\''s'");
}

TEST(SlurmLauncher, DecodesTheSlurmOptionOfTheLauncherGroup) {
  const SlurmLauncherOptions defaults =
      DecodeSlurmLauncherOptions(DemoLauncher({"hydra/launcher=slurm"}));
  EXPECT_TRUE(defaults.wait);
  EXPECT_EQ(defaults.array_parallelism, 256);
  EXPECT_EQ(defaults.cpus_per_task, 1);  // ${threads} of demo.yaml
  EXPECT_FALSE(defaults.mem_gb.has_value());
  EXPECT_TRUE(defaults.partition.empty());

  const SlurmLauncherOptions set = DecodeSlurmLauncherOptions(
      DemoLauncher({"hydra/launcher=slurm",
                    "hydra.launcher.wait=false",
                    "hydra.launcher.partition=gpu",
                    "hydra.launcher.mem_gb=1.5",
                    "+hydra.launcher.additional_parameters.mail_type=END",
                    "hydra.launcher.setup=[module load cuda]"}));
  EXPECT_FALSE(set.wait);
  EXPECT_EQ(set.partition, "gpu");
  ASSERT_TRUE(set.mem_gb.has_value());
  EXPECT_DOUBLE_EQ(*set.mem_gb, 1.5);
  ASSERT_EQ(set.additional_parameters.size(), 1u);
  EXPECT_EQ(set.additional_parameters[0].first, "mail_type");
  EXPECT_EQ(set.setup, std::vector<std::string>{"module load cuda"});
}

TEST(SlurmLauncher, RejectsBadOptionsNamingTheKey) {
  const std::string bad_value = testing::ErrorMessage<ConfigError>([] {
    DecodeSlurmLauncherOptions(DemoLauncher(
        {"hydra/launcher=slurm", "hydra.launcher.array_parallelism=0"}));
  });
  EXPECT_TRUE(Contains(bad_value, "hydra.launcher.array_parallelism = 0"))
      << bad_value;
  const std::string unknown = testing::ErrorMessage<ConfigError>([] {
    DecodeSlurmLauncherOptions(
        DemoLauncher({"hydra/launcher=slurm", "+hydra.launcher.nodes=2"}));
  });
  EXPECT_TRUE(Contains(unknown, "nodes")) << unknown;
}

TEST(SlurmLauncher, ScriptCarriesResourcesAndOneCasePerJob) {
  SlurmLauncherOptions options;
  options.array_parallelism = 2;
  options.partition = "debug";
  options.cpus_per_task = 4;
  options.mem_gb = 1.5;
  options.timeout_min = 30;
  options.gres = "gpu:1";
  options.account = "lab";
  options.qos = "high";
  options.constraint = "a100";
  options.signal_delay_s = 90;
  options.setup = {"module load cuda", "export OMP_NUM_THREADS=4"};
  options.additional_parameters = {{"mail_type", "END"}, {"exclusive", ""}};
  const fs::path sweep = "/sweeps/s1";
  const std::string script =
      MakeSbatchScript(options, Spec(sweep, "/opt/soma/bin/soma"));
  for (const char* line : {"#!/bin/bash\n",
                           "#SBATCH --job-name=soma\n",
                           "#SBATCH --array=1,3%2\n",
                           "#SBATCH --chdir=/sweeps/s1\n",
                           "#SBATCH --output=/sweeps/s1/.slurm/tasks/%a/"
                           "slurm-%A_%a.out\n",
                           "#SBATCH --error=/sweeps/s1/.slurm/tasks/%a/"
                           "slurm-%A_%a.err\n",
                           "#SBATCH --partition=debug\n",
                           "#SBATCH --cpus-per-task=4\n",
                           "#SBATCH --mem=1536M\n",
                           "#SBATCH --time=30\n",
                           "#SBATCH --gres=gpu:1\n",
                           "#SBATCH --account=lab\n",
                           "#SBATCH --qos=high\n",
                           "#SBATCH --constraint=a100\n",
                           "#SBATCH --signal=B:USR1@90\n",
                           "#SBATCH --requeue\n",
                           "#SBATCH --mail-type=END\n",
                           "#SBATCH --exclusive\n",
                           "module load cuda\nexport OMP_NUM_THREADS=4\n",
                           "  1)\n    job_dir='/sweeps/s1/1'\n"
                           "    overrides=('a=1' 'b=it'\\''s')\n",
                           "  3)\n    job_dir='/sweeps/s1/3'\n"
                           "    overrides=('a=3' 'b=x y')\n",
                           "export SOMA_SWEEP_DIR='/sweeps/s1'\n",
                           "'/opt/soma/bin/soma' '-m' '-cn' 'demo' "
                           "\"${overrides[@]}\" &\n"}) {
    EXPECT_TRUE(Contains(script, line)) << "missing: " << line << "\n"
                                        << script;
  }
  // Every #SBATCH line comes before the first command (sbatch stops there).
  EXPECT_LT(script.rfind("#SBATCH"), script.find("set -u"));
  // Optional resources are left out when unset.
  const std::string plain =
      MakeSbatchScript(SlurmLauncherOptions{}, Spec(sweep, "/x/soma"));
  for (const char* flag : {"--partition",
                           "--mem",
                           "--gres",
                           "--account",
                           "--qos",
                           "--constraint"}) {
    EXPECT_FALSE(Contains(plain, flag)) << flag;
  }
  EXPECT_TRUE(Contains(plain, "#SBATCH --array=1,3%256\n"));
}

/// Runs the generated script with bash as array task `task`, with `exe` as
/// soma; returns bash's exit status.
int RunScriptAsTask(const fs::path& sweep, const std::string& exe, int task) {
  const std::string script =
      MakeSbatchScript(SlurmLauncherOptions{}, Spec(sweep, exe));
  WriteFileAtomic(sweep / "array.sbatch", script);
  const std::string command =
      "SLURM_ARRAY_TASK_ID=" + std::to_string(task) + " bash " +
      ShellQuote((sweep / "array.sbatch").string()) + " >" +
      ShellQuote((sweep / "out.txt").string()) + " 2>&1";
  const int status = std::system(command.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(SlurmLauncher, WrapperRecordsTheJobsOwnExitStatus) {
  const fs::path sweep = testing::CreateTestDir();
  fs::create_directories(sweep / "1");
  fs::create_directories(sweep / "3");
  // A stand-in for soma that prints its arguments and environment and fails
  // with status 3 for job 3.
  testing::WriteTextFile(sweep,
                         "fake_soma.sh",
                         "#!/bin/bash\n"
                         "echo \"job=$SOMA_SWEEP_JOB dir=$SOMA_SWEEP_DIR "
                         "args=$*\"\n"
                         "[[ $SOMA_SWEEP_JOB == 3 ]] && exit 3\nexit 0\n");
  fs::permissions(sweep / "fake_soma.sh", fs::perms::owner_all);
  const std::string exe = (sweep / "fake_soma.sh").string();

  EXPECT_EQ(RunScriptAsTask(sweep, exe, 1), 0);
  EXPECT_EQ(ReadFile(sweep / "1" / kExitStatusFile), "0\n");
  EXPECT_TRUE(
      Contains(ReadFile(sweep / "out.txt"),
               "job=1 dir=" + sweep.string() + " args=-m -cn demo a=1 b=it's"))
      << ReadFile(sweep / "out.txt");

  EXPECT_EQ(RunScriptAsTask(sweep, exe, 3), 3);
  EXPECT_EQ(ReadFile(sweep / "3" / kExitStatusFile), "3\n");

  // A task id that is no job of the array fails without running anything.
  EXPECT_EQ(RunScriptAsTask(sweep, exe, 2), 2);
  EXPECT_TRUE(Contains(ReadFile(sweep / "out.txt"), "no job for array task"));
}

/// Runs the script as array task 1 with a fake `scontrol` on PATH, sends
/// the wrapper SIGUSR1 once the stand-in soma runs; returns bash's status.
int PreemptTask(const fs::path& sweep, bool requeue) {
  testing::WriteTextFile(
      sweep, "bin/scontrol", "#!/bin/bash\necho \"$*\" > \"$SCONTROL_LOG\"\n");
  testing::WriteTextFile(sweep,
                         "sleeping_soma.sh",
                         "#!/bin/bash\ntouch \"$SOMA_SWEEP_DIR/started\"\n"
                         "exec sleep 30\n");
  for (const char* exe : {"bin/scontrol", "sleeping_soma.sh"}) {
    fs::permissions(sweep / exe, fs::perms::owner_all);
  }
  SlurmLauncherOptions options;
  options.requeue = requeue;
  WriteFileAtomic(
      sweep / "array.sbatch",
      MakeSbatchScript(options,
                       Spec(sweep, (sweep / "sleeping_soma.sh").string())));
  fs::remove(sweep / "started");
  const std::string q = ShellQuote(sweep.string());
  const std::string command =
      "cd " + q + " && (SLURM_ARRAY_TASK_ID=1 SLURM_JOB_ID=77 " +
      "SCONTROL_LOG=" + q + "/scontrol.log PATH=" + q +
      "/bin:$PATH bash array.sbatch >out.txt 2>&1 & p=$!; " +
      "for i in $(seq 100); do [ -f started ] && break; sleep 0.1; done; " +
      "sleep 0.3; kill -USR1 $p; wait $p; echo $? > rc.txt)";
  if (std::system(command.c_str()) != 0) return -1;
  return std::stoi(ReadFile(sweep / "rc.txt"));
}

TEST(SlurmLauncher, WrapperRequeuesOnSigusr1) {
  const fs::path sweep = testing::CreateTestDir();
  fs::create_directories(sweep / "1");
  EXPECT_EQ(PreemptTask(sweep, /*requeue=*/true), 0);
  EXPECT_EQ(ReadFile(sweep / "scontrol.log"), "requeue 77\n");
  EXPECT_FALSE(fs::exists(sweep / "1" / kExitStatusFile));
  EXPECT_TRUE(Contains(ReadFile(sweep / "out.txt"), "requeued SLURM job 77"))
      << ReadFile(sweep / "out.txt");

  // Without requeue the job just ends, stopped by the SIGUSR1 the wrapper
  // passed on (128 + 10; a training checkpoints first).
  fs::remove(sweep / "scontrol.log");
  EXPECT_EQ(PreemptTask(sweep, /*requeue=*/false), 128 + SIGUSR1);
  EXPECT_FALSE(fs::exists(sweep / "scontrol.log"));
  EXPECT_EQ(ReadFile(sweep / "1" / kExitStatusFile),
            std::to_string(128 + SIGUSR1) + "\n");
}

TEST(SlurmLauncher, MissingSbatchSubmitsNothing) {
  const fs::path sweep = testing::CreateTestDir();
  const char* old_path = std::getenv("PATH");
  const std::string saved = old_path ? old_path : "";
  ::setenv("PATH", (sweep / "empty_bin").c_str(), 1);
  const std::string message = testing::ErrorMessage<Error>([&] {
    SubmitSlurmArray(SlurmLauncherOptions{}, Spec(sweep, "/x/soma"));
  });
  ::setenv("PATH", saved.c_str(), 1);
  EXPECT_TRUE(Contains(message, "'sbatch'")) << message;
  EXPECT_TRUE(Contains(message, "nothing was submitted")) << message;
  EXPECT_FALSE(fs::exists(sweep / ".slurm"));
}

}  // namespace
}  // namespace soma
