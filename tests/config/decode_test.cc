#include "framework/config/decode.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace soma {
namespace {

TEST(ConfigReader, OneOrMoreReadsAStringAsAOneElementList) {
  const ConfigNode node =
      ParseYaml("one: a.pt\nmany: [a.pt, b.pt]\nnone: null\n", "test.yaml");
  ConfigReader reader(node);
  std::vector<std::string> one, many, none = {"kept?"};
  reader.ReadOneOrMore("one", &one);
  reader.RequireOneOrMore("many", &many);
  reader.ReadOneOrMore("none", &none);
  reader.Finish();
  EXPECT_EQ(one, std::vector<std::string>{"a.pt"});
  EXPECT_EQ(many, (std::vector<std::string>{"a.pt", "b.pt"}));
  EXPECT_TRUE(none.empty());
  ConfigReader absent(node);
  EXPECT_THROW(absent.RequireOneOrMore("other", &one), ConfigError);
}

TEST(ConfigReader, AMissingListIsAMissingMandatoryValue) {
  const ConfigNode node = ParseYaml("list: ???\nnumber: 3\n", "test.yaml");
  ConfigReader reader(node);
  std::vector<std::string> list;
  EXPECT_THROW(reader.Read("list", &list), MissingMandatoryValue);
  EXPECT_THROW(reader.ReadOneOrMore("list", &list), MissingMandatoryValue);
  std::vector<double> numbers;
  try {
    reader.Read("number", &numbers);
    FAIL() << "a scalar is not a list";
  } catch (const MissingMandatoryValue&) {
    FAIL() << "a scalar is not a missing value";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("Expected a list"), std::string::npos);
  }
}

}  // namespace
}  // namespace soma
