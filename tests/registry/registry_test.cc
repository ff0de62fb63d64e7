#include "framework/registry/registry.h"

#include "framework/config/yaml_io.h"

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

}  // namespace
}  // namespace soma
