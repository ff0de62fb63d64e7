// The global registries after InitFramework(): frozen, and Instantiate() on
// the registered tasks (moved from tests/registry/registry_test.cc: they need
// the whole framework initialised, above the registry module).
#include "framework/config/yaml_io.h"
#include "framework/registry/registry.h"
#include "framework/tasks/task.h"

#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

ConfigNode Yaml(const std::string& text) { return ParseYaml(text, "<test>"); }

TEST(Registry, GlobalRegistriesAreFrozenAfterInit) {
  EXPECT_TRUE(RegistriesFrozen());
  EXPECT_THROW(
      GetRegistry<Task>().Register("late",
                                   [](const ConfigNode&, BuildContext&) {
                                     return std::unique_ptr<Task>();
                                   }),
      InternalError);
}

TEST(Instantiate, UnknownTaskNameListsRegisteredTasks) {
  ConfigNode root = Yaml("task:\n  name: trian\n");
  BuildContext ctx;
  try {
    Instantiate<Task>(root.at("task"), ctx);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("task = trian"), std::string::npos) << what;
    EXPECT_NE(what.find("demo"), std::string::npos) << what;
  }
}

TEST(Instantiate, MissingTargetIsAnError) {
  ConfigNode root = Yaml("task:\n  steps: 3\n");
  BuildContext ctx;
  EXPECT_THROW(Instantiate<Task>(root.at("task"), ctx), ConfigError);
}

TEST(Instantiate, UnknownOptionOfAComponentIsAnError) {
  ConfigNode root = Yaml("task:\n  name: demo\n  stepz: 3\n");
  BuildContext ctx;
  try {
    Instantiate<Task>(root.at("task"), ctx);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown key 'stepz'"),
              std::string::npos)
        << e.what();
  }
}

TEST(Instantiate, CallSiteOverridesAreMerged) {
  ConfigNode root = Yaml("task:\n  _target_: demo\n  steps: 3\n");
  BuildContext ctx;
  ConfigNode overrides = ConfigNode::EmptyMap();
  overrides.Set("lr", ConfigNode(2.0));  // violates 0 < lr < 1
  EXPECT_NO_THROW(Instantiate<Task>(root.at("task"), ctx));
  EXPECT_THROW(Instantiate<Task>(root.at("task"), ctx, overrides), ConfigError);
}

}  // namespace
}  // namespace soma
