#include "framework/registry/registry.h"

#include "framework/config/yaml_io.h"
#include "framework/tasks/task.h"

#include <gtest/gtest.h>

#include <string>

namespace soma {
namespace {

struct Shape {
  static constexpr std::string_view kRegistryName = "shape";
  virtual ~Shape() = default;
  virtual double Area() const = 0;
};

struct Square : Shape {
  explicit Square(double side) : side(side) {}
  double Area() const override { return side * side; }
  double side;
};

ConfigNode Yaml(const std::string& text) { return ParseYaml(text, "<test>"); }

TEST(Registry, CreatesRegisteredComponent) {
  Registry<Shape> registry("shape");
  registry.Register("square", [](const ConfigNode& node, BuildContext&) {
    return std::make_unique<Square>(node.at("side").AsDouble());
  });
  BuildContext ctx;
  auto shape = registry.Create("square", Yaml("side: 3.0"), ctx);
  EXPECT_DOUBLE_EQ(shape->Area(), 9.0);
}

TEST(Registry, DuplicateKeyThrows) {
  Registry<Shape> registry("shape");
  auto creator = [](const ConfigNode&, BuildContext&) {
    return std::make_unique<Square>(1.0);
  };
  registry.Register("square", creator);
  EXPECT_THROW(registry.Register("square", creator), InternalError);
}

TEST(Registry, UnknownKeyListsSortedAlternativesAndPath) {
  Registry<Shape> registry("shape");
  auto creator = [](const ConfigNode&, BuildContext&) {
    return std::make_unique<Square>(1.0);
  };
  registry.Register("square", creator);
  registry.Register("circle", creator);
  ConfigNode root = Yaml("model:\n  shape:\n    name: hexagon\n");
  BuildContext ctx;
  try {
    registry.Create("hexagon", root.at("model").at("shape"), ctx);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("model.shape = hexagon"), std::string::npos) << what;
    EXPECT_NE(what.find("circle, square"), std::string::npos) << what;
  }
}

TEST(Registry, KeysAreSorted) {
  Registry<Shape> registry("shape");
  auto creator = [](const ConfigNode&, BuildContext&) {
    return std::make_unique<Square>(1.0);
  };
  registry.Register("b", creator);
  registry.Register("a", creator);
  EXPECT_EQ(registry.Keys(), (std::vector<std::string>{"a", "b"}));
}

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
