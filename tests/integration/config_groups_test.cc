// Walks every config group under configs/ and builds each option through the
// registry, so a YAML file whose component is missing (or whose options the
// component rejects) fails CI.
#include "framework/config/compose.h"
#include "framework/config/interpolation.h"
#include "framework/registry/registry.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

bool HasMissingValue(const ConfigNode& node) {
  if (node.IsMissing()) return true;
  if (node.IsMap()) {
    for (const auto& [key, child] : node.entries()) {
      if (HasMissingValue(child)) return true;
    }
  }
  if (node.IsList()) {
    for (const ConfigNode& child : node.items()) {
      if (HasMissingValue(child)) return true;
    }
  }
  return false;
}

std::string PackageOf(const std::string& group) {
  std::string package = group;
  for (char& c : package) {
    if (c == '/') c = '.';
  }
  return package;
}

TEST(ConfigGroups, EveryOptionComposesAndBuilds) {
  const std::string configs = (testing::SourceDir() / "configs").string();
  ConfigRepository repo({configs});
  const ComposeResult base = Compose(ComposeRequest{.search_path = {configs}});
  int built = 0;
  for (const std::string& group : repo.Groups()) {
    const bool selected_by_default =
        base.root.FindPath("hydra.runtime.choices") != nullptr &&
        base.root.FindPath("hydra.runtime.choices")->Find(group) != nullptr;
    for (const std::string& option : repo.Options(group)) {
      SCOPED_TRACE(group + "/" + option);
      ComposeRequest request{.search_path = {configs}};
      request.overrides.push_back(ParseOverride(
          (selected_by_default ? "" : "+") + group + "=" + option));
      ComposeResult result;
      ASSERT_NO_THROW(result = Compose(request));
      const ConfigNode resolved = Resolve(result.root, DefaultResolvers());
      const auto& builders = ConfigGroupBuilders();
      auto it = builders.find(group);
      const ConfigNode* node = resolved.FindPath(PackageOf(group));
      if (it == builders.end()) {
        // Not a component group (e.g. experiment): it must not pretend to be
        // one.
        if (node != nullptr && node->IsMap()) {
          EXPECT_EQ(node->Find("_target_"), nullptr)
              << "group '" << group << "' has _target_ but no registry";
        }
        continue;
      }
      ASSERT_NE(node, nullptr);
      BuildContext ctx;
      if (HasMissingValue(*node)) {
        // An option with a mandatory value (e.g. a user's model path) must
        // refuse to build with the full key path in the message.
        try {
          it->second.build(*node, ctx);
          ADD_FAILURE() << "built although a mandatory value is missing";
        } catch (const MissingMandatoryValue& e) {
          EXPECT_NE(std::string(e.what()).find(PackageOf(group) + "."),
                    std::string::npos)
              << e.what();
        }
        continue;
      }
      EXPECT_NO_THROW(it->second.build(*node, ctx));
      ++built;
    }
  }
  EXPECT_GT(built, 0);
}

}  // namespace
}  // namespace soma
