#include "framework/config/interpolation.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/testing/testing.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>
#include <vector>

namespace soma {
namespace {

using testing::ErrorMessage;

/// OmegaConf's docs/source/config_interpolation.yaml tutorial (plus the
/// plan-selection example of the interpolation docs).
const char* const kTutorialYaml = R"(plans:
  A: plan A
  B: plan B
selected_plan: A
plan: ${plans[${selected_plan}]}
server:
  host: localhost
  port: 80
client:
  url: http://${server.host}:${server.port}/
  server_port: ${server.port}
  description: Client of ${.url}
)";

TEST(Interpolation, TutorialTypePreservation) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(kTutorialYaml, "config_interpolation.yaml");
  const ConfigNode port = Select(cfg, "client.server_port", resolvers);
  ASSERT_TRUE(port.IsInt());
  EXPECT_EQ(port.AsInt(), 80);
  EXPECT_EQ(port.path(), "client.server_port");
  EXPECT_EQ(Select(cfg, "client.url", resolvers).AsString(),
            "http://localhost:80/");
  EXPECT_EQ(Select(cfg, "client.description", resolvers).AsString(),
            "Client of http://localhost:80/");
  EXPECT_EQ(Select(cfg, "plan", resolvers).AsString(), "plan A");
}

TEST(Interpolation, ResolveWholeTreeKeepsPathsAndSources) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(kTutorialYaml, "config_interpolation.yaml");
  const ConfigNode resolved = Resolve(cfg, resolvers);
  EXPECT_EQ(resolved.FindPath("client.server_port")->AsInt(), 80);
  EXPECT_EQ(resolved.FindPath("client.server_port")->source().ToString(),
            "config_interpolation.yaml:11");
  EXPECT_EQ(resolved.FindPath("client.url")->path(), "client.url");
  EXPECT_EQ(resolved.FindPath("plan")->AsString(), "plan A");
  EXPECT_EQ(resolved.Keys(), cfg.Keys());
  // The input is untouched.
  EXPECT_TRUE(cfg.FindPath("client.url")->IsInterpolation());
}

TEST(Interpolation, NestedSelectionFollowsTheSelector) {
  const ResolverRegistry resolvers;
  ConfigNode cfg = ParseYaml(kTutorialYaml, "c.yaml");
  cfg.Set("selected_plan", "B");
  EXPECT_EQ(Select(cfg, "plan", resolvers).AsString(), "plan B");
}

TEST(Interpolation, MapReferenceYieldsResolvedSubtree) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "base:\n  lr: 0.1\n  scaled: ${.lr}\n  nested: {x: '${base.lr}'}\n"
      "copy: ${base}\n"
      "deep: ${copy.nested.x}\n",
      "m.yaml");
  const ConfigNode copy = Select(cfg, "copy", resolvers);
  ASSERT_TRUE(copy.IsMap());
  EXPECT_DOUBLE_EQ(copy.at("scaled").AsDouble(), 0.1);
  EXPECT_DOUBLE_EQ(copy.at("nested").at("x").AsDouble(), 0.1);
  EXPECT_EQ(copy.at("nested").at("x").path(), "copy.nested.x");
  EXPECT_DOUBLE_EQ(Select(cfg, "deep", resolvers).AsDouble(), 0.1);
}

TEST(Interpolation, RelativeKeysClimbOneLevelPerDot) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "x: top\n"
      "a:\n"
      "  x: mid\n"
      "  b:\n"
      "    x: low\n"
      "    sibling: ${.x}\n"
      "    parent: ${..x}\n"
      "    grand: ${...x}\n"
      "    too_far: ${....x}\n"
      "list:\n"
      "  - 10\n"
      "  - ${.0}\n"
      "  - ${..x}\n",
      "rel.yaml");
  EXPECT_EQ(Select(cfg, "a.b.sibling", resolvers).AsString(), "low");
  EXPECT_EQ(Select(cfg, "a.b.parent", resolvers).AsString(), "mid");
  EXPECT_EQ(Select(cfg, "a.b.grand", resolvers).AsString(), "top");
  EXPECT_THROW(Select(cfg, "a.b.too_far", resolvers), InterpolationKeyError);
  EXPECT_EQ(Select(cfg, "list[1]", resolvers).AsInt(), 10);
  EXPECT_EQ(Select(cfg, "list[2]", resolvers).AsString(), "top");
}

TEST(Interpolation, BracketAndIndexKeys) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "l: [a, b, c]\n"
      "i: 2\n"
      "m: {k: {z: 1}}\n"
      "sel: k\n"
      "first: ${l[0]}\n"
      "by_dot: ${l.1}\n"
      "by_ref: ${l[${i}]}\n"
      "dict: ${m[k].z}\n"
      "nested: ${m[${sel}][z]}\n",
      "b.yaml");
  EXPECT_EQ(Select(cfg, "first", resolvers).AsString(), "a");
  EXPECT_EQ(Select(cfg, "by_dot", resolvers).AsString(), "b");
  EXPECT_EQ(Select(cfg, "by_ref", resolvers).AsString(), "c");
  EXPECT_EQ(Select(cfg, "dict", resolvers).AsInt(), 1);
  EXPECT_EQ(Select(cfg, "nested", resolvers).AsInt(), 1);
}

TEST(Interpolation, EmbeddedValuesUsePythonStr) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "i: 1\nf: 0.1\nt: true\nn: null\ns: x\nl: [1, a]\n"
      "out: ${i}-${f}-${t}-${n}-${s}-${l}\n"
      "spaced: ' ${i}'\n",
      "s.yaml");
  EXPECT_EQ(Select(cfg, "out", resolvers).AsString(),
            "1-0.1-True-None-x-[1, 'a']");
  const ConfigNode spaced = Select(cfg, "spaced", resolvers);
  ASSERT_TRUE(spaced.IsString());
  EXPECT_EQ(spaced.AsString(), " 1");
}

TEST(Interpolation, WhitespaceInsideBraces) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml("a: 3\nb: ${ a }\n", "w.yaml");
  EXPECT_EQ(Select(cfg, "b", resolvers).AsInt(), 3);
}

TEST(Interpolation, MissingValueRaisesOnAccessWithFullPath) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "train:\n  batch_size: ???\n  lr: 0.1\n"
      "data:\n  batch: ${train.batch_size}\n",
      "train.yaml");
  // Selecting the subtree works; reading the key raises.
  const ConfigNode train = Select(cfg, "train", resolvers);
  EXPECT_DOUBLE_EQ(train.at("lr").AsDouble(), 0.1);
  EXPECT_TRUE(train.at("batch_size").IsMissing());
  const std::string message = ErrorMessage<MissingMandatoryValue>(
      [&] { train.at("batch_size").AsInt(); });
  EXPECT_EQ(message.rfind("MissingMandatoryValue: train.batch_size", 0), 0u)
      << message;
  EXPECT_TRUE(Select(cfg, "train.batch_size", resolvers).IsMissing());

  // A reference to `???` raises, naming the target key.
  const std::string ref = ErrorMessage<MissingMandatoryValue>(
      [&] { Select(cfg, "data.batch", resolvers); });
  EXPECT_EQ(ref.rfind("MissingMandatoryValue: train.batch_size", 0), 0u) << ref;
  EXPECT_NE(ref.find("data.batch"), std::string::npos) << ref;

  // Whole-tree resolution keeps missing values missing (OmegaConf.resolve).
  const ConfigNode resolved = Resolve(cfg, resolvers);
  EXPECT_TRUE(resolved.FindPath("train.batch_size")->IsMissing());
  EXPECT_TRUE(resolved.FindPath("data.batch")->IsMissing());
}

TEST(Interpolation, ListsOfMapsAndInterpolatedIntermediates) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "items:\n  - name: a\n  - name: b\n"
      "alias: ${items}\n"
      "second: ${items[1].name}\n"
      "through_alias: ${alias[0].name}\n",
      "l.yaml");
  EXPECT_EQ(Select(cfg, "second", resolvers).AsString(), "b");
  EXPECT_EQ(Select(cfg, "through_alias", resolvers).AsString(), "a");
  const ConfigNode alias = Select(cfg, "alias", resolvers);
  ASSERT_TRUE(alias.IsList());
  EXPECT_EQ(alias.at(size_t{1}).at("name").path(), "alias[1].name");
}

TEST(Interpolation, StringInterpolationOfMissingBecomesMissingOnResolve) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg =
      ParseYaml("m: \"???\"\nname: run_${m}\nuse: ${name}\n", "m.yaml");
  const ConfigNode resolved = Resolve(cfg, resolvers);
  EXPECT_TRUE(resolved.at("name").IsMissing());
  EXPECT_TRUE(resolved.at("use").IsMissing());
  EXPECT_THROW(Select(cfg, "name", resolvers), MissingMandatoryValue);
  const std::string message = ErrorMessage<MissingMandatoryValue>(
      [&] { resolved.at("use").AsString(); });
  EXPECT_EQ(message.rfind("MissingMandatoryValue: use", 0), 0u) << message;
}

TEST(Interpolation, MissingKeyIsInterpolationKeyError) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml("x: {}\na:\n  b: ${x.y}\n", "k.yaml");
  const std::string message = ErrorMessage<InterpolationKeyError>(
      [&] { Select(cfg, "a.b", resolvers); });
  EXPECT_EQ(message.rfind("InterpolationKeyError: Interpolation key 'x.y' not "
                          "found (while resolving 'a.b')",
                          0),
            0u)
      << message;
  EXPECT_NE(message.find("k.yaml:3"), std::string::npos) << message;
  EXPECT_THROW(Resolve(cfg, resolvers), InterpolationKeyError);
}

TEST(Interpolation, SelectOfAnAbsentKeyThrows) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml("a: 1\n", "k.yaml");
  EXPECT_THROW(Select(cfg, "b", resolvers), ConfigError);
}

// OmegaConf's wording ("Recursive interpolation detected") plus the chain.
TEST(Interpolation, CyclesAreReportedWithTheChain) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "a: ${b}\nb: ${a}\nself: x${self}\nc: {d: '${c}'}\n", "cy.yaml");
  EXPECT_EQ(ErrorMessage<ConfigError>([&] { Select(cfg, "a", resolvers); }),
            "InterpolationResolutionError: Recursive interpolation detected. "
            "Interpolation cycle: a -> b -> a");
  EXPECT_EQ(ErrorMessage<ConfigError>([&] { Select(cfg, "self", resolvers); }),
            "InterpolationResolutionError: Recursive interpolation detected. "
            "Interpolation cycle: self -> self");
  EXPECT_EQ(ErrorMessage<ConfigError>([&] { Select(cfg, "c", resolvers); }),
            "InterpolationResolutionError: Recursive interpolation detected. "
            "Interpolation cycle: c -> c.d -> c");
  EXPECT_THROW(Resolve(cfg, resolvers), ConfigError);
}

TEST(Interpolation, LazySelectIgnoresBrokenSiblings) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg =
      ParseYaml("ok: ${v}\nv: 1\nbroken: ${nope}\n", "lazy.yaml");
  EXPECT_EQ(Select(cfg, "ok", resolvers).AsInt(), 1);
}

TEST(Interpolation, EscapedInterpolationIsLiteral) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "v: 5\n"
      "esc: \\${v}\n"
      "mixed: \\${v} is ${v}\n"
      "backslash: \\\\${v}\n"
      "ref: ${esc}\n",
      "esc.yaml");
  const ConfigNode esc = Select(cfg, "esc", resolvers);
  ASSERT_TRUE(esc.IsString());
  EXPECT_EQ(esc.AsString(), "${v}");
  EXPECT_EQ(Select(cfg, "mixed", resolvers).AsString(), "${v} is 5");
  EXPECT_EQ(Select(cfg, "backslash", resolvers).AsString(), "\\5");
  EXPECT_EQ(Select(cfg, "ref", resolvers).AsString(), "${v}");
  const ConfigNode resolved = Resolve(cfg, resolvers);
  EXPECT_EQ(resolved.at("mixed").AsString(), "${v} is 5");
  // The resolved tree dumps and re-reads to the same literal.
  EXPECT_EQ(ParseYaml(DumpYaml(resolved), "re.yaml"), resolved);
}

TEST(Interpolation, GrammarErrorsAreConfigErrors) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml("a: ${b\nc: ${}\nd: ${x[}\n", "g.yaml");
  for (const char* key : {"a", "c", "d"}) {
    const std::string message =
        ErrorMessage<ConfigError>([&] { Select(cfg, key, resolvers); });
    EXPECT_EQ(message.rfind("GrammarParseError", 0), 0u) << message;
    EXPECT_NE(message.find(fmt::format("'{}'", key)), std::string::npos)
        << message;
  }
}

TEST(Interpolation, ResolveStringUsesNodePathForRelativeKeys) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml("a:\n  b: 1\n  c: 2\n", "r.yaml");
  const ConfigNode whole = ResolveString(cfg, "${.b}", "a.c", resolvers);
  ASSERT_TRUE(whole.IsInt());
  EXPECT_EQ(whole.AsInt(), 1);
  EXPECT_EQ(ResolveString(cfg, "v${a.b}${a.c}", "", resolvers).AsString(),
            "v12");
  EXPECT_EQ(ResolveString(cfg, "no interpolation", "", resolvers).AsString(),
            "no interpolation");
}

TEST(Interpolation, HasInterpolation) {
  EXPECT_TRUE(HasInterpolation("${a}"));
  EXPECT_TRUE(HasInterpolation("x ${a} y"));
  EXPECT_TRUE(HasInterpolation("\\\\${a}"));
  EXPECT_FALSE(HasInterpolation("\\${a}"));
  EXPECT_FALSE(HasInterpolation("$a {b}"));
  EXPECT_FALSE(HasInterpolation(""));
}

// ---------------------------------------------------------------------------
// Resolvers.

TEST(Resolvers, UnknownResolverUsesHydraWording) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "subject: ${resolve_mocap_subject:${mocap.fname}}\nmocap: {fname: x}\n",
      "u.yaml");
  const std::string message =
      ErrorMessage<ConfigError>([&] { Select(cfg, "subject", resolvers); });
  EXPECT_EQ(message.rfind("Unsupported interpolation type "
                          "resolve_mocap_subject",
                          0),
            0u)
      << message;
  EXPECT_NE(message.find("oc.env"), std::string::npos) << message;
  EXPECT_THROW(resolvers.Get("nope"), ConfigError);
}

TEST(Resolvers, UserResolverWithNestedInterpolatedArguments) {
  ResolverRegistry resolvers;
  resolvers.Register(
      "resolve_data_id",
      [](const std::vector<ConfigNode>& args, const ResolverCall&) {
        return ConfigNode(fmt::format(
            "OC_{:02d}_G_{:02d}", args.at(0).AsInt(), args.at(1).AsInt()));
      });
  const ConfigNode cfg = ParseYaml(
      "noise:\n  num_occ_max: 5\n  num_ghost_max: 3\n"
      "data_id: "
      "${resolve_data_id:${noise.num_occ_max},${noise.num_ghost_max}}\n"
      "work_dir: /work/${data_id}/run\n",
      "soma.yaml");
  EXPECT_EQ(Select(cfg, "data_id", resolvers).AsString(), "OC_05_G_03");
  EXPECT_EQ(Select(cfg, "work_dir", resolvers).AsString(),
            "/work/OC_05_G_03/run");
  EXPECT_THROW(
      resolvers.Register("resolve_data_id",
                         [](const std::vector<ConfigNode>&,
                            const ResolverCall&) { return ConfigNode(); }),
      ConfigError);
}

TEST(Resolvers, ArgumentsAreTypedTrimmedAndUnescaped) {
  ResolverRegistry resolvers;
  resolvers.Register(
      "describe",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        std::vector<std::string> parts;
        for (const ConfigNode& arg : args) {
          parts.push_back(fmt::format(
              "{}:{}", ConfigNode::TypeName(arg.type()), DumpFlow(arg)));
        }
        parts.push_back(std::string(call.node_path));
        return ConfigNode::LiteralString(
            fmt::format("{}", fmt::join(parts, "|")));
      });
  const ConfigNode cfg = ParseYaml(
      "v: 7\n"
      "a: '${describe: 1 , 1.5,true, null,abc , 1e-3,1_000, inf}'\n"
      "b: '${describe:''x, y'',\"q\",a\\, b,a b,${v},x${v}, \\ }'\n"
      "c: '${describe:[1,${v}],{k: v},,}'\n"
      "d: ${describe:}\n",
      "args.yaml");
  EXPECT_EQ(Select(cfg, "a", resolvers).AsString(),
            "int:1|float:1.5|bool:true|None:null|str:abc|float:0.001|"
            "int:1000|float:inf|a");
  EXPECT_EQ(Select(cfg, "b", resolvers).AsString(),
            "str:'x, y'|str:q|str:'a, b'|str:a b|int:7|str:x7|str:' '|b");
  EXPECT_EQ(Select(cfg, "c", resolvers).AsString(),
            "list:[1,7]|dict:{k:v}|str:''|str:''|c");
  EXPECT_EQ(Select(cfg, "d", resolvers).AsString(), "d");
}

TEST(Resolvers, NowIsCachedPerPatternPerRegistry) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "day: ${now:%Y-%m-%d}\n"
      "default: ${now:}\n"
      "dir: outputs/${now:%Y-%m-%d}/${now:%H-%M-%S}\n",
      "now.yaml");
  const std::string day = Select(cfg, "day", resolvers).AsString();
  EXPECT_EQ(day.size(), 10u);
  EXPECT_EQ(day, resolvers.CachedNow("%Y-%m-%d"));
  EXPECT_EQ(Select(cfg, "default", resolvers).AsString().size(),
            std::string("2024-01-01_12-00-00").size());
  const std::string dir = Select(cfg, "dir", resolvers).AsString();
  EXPECT_EQ(dir, Select(cfg, "dir", resolvers).AsString());
  EXPECT_EQ(dir, "outputs/" + day + "/" + resolvers.CachedNow("%H-%M-%S"));
}

TEST(Resolvers, OcEnvReturnsStrings) {
  const ResolverRegistry resolvers;
  ::setenv("SOMA_TEST_ENV_NUMBER", "42", 1);
  ::unsetenv("SOMA_TEST_ENV_UNSET");
  const ConfigNode cfg = ParseYaml(
      "num: ${oc.env:SOMA_TEST_ENV_NUMBER}\n"
      "def: ${oc.env:SOMA_TEST_ENV_UNSET,fallback}\n"
      "def_num: ${oc.env:SOMA_TEST_ENV_UNSET,5}\n"
      "def_null: ${oc.env:SOMA_TEST_ENV_UNSET,null}\n"
      "unset: ${oc.env:SOMA_TEST_ENV_UNSET}\n",
      "env.yaml");
  const ConfigNode num = Select(cfg, "num", resolvers);
  ASSERT_TRUE(num.IsString());
  EXPECT_EQ(num.AsString(), "42");
  EXPECT_EQ(Select(cfg, "def", resolvers).AsString(), "fallback");
  EXPECT_EQ(Select(cfg, "def_num", resolvers).AsString(), "5");
  EXPECT_TRUE(Select(cfg, "def_null", resolvers).IsNull());
  const std::string message =
      ErrorMessage<ConfigError>([&] { Select(cfg, "unset", resolvers); });
  // OmegaConf's wording.
  EXPECT_NE(
      message.find("Environment variable 'SOMA_TEST_ENV_UNSET' not found"),
      std::string::npos)
      << message;
}

TEST(Resolvers, OcSelect) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "a:\n  x: 1\n  m: ???\n"
      "  rel: ${oc.select:.x,0}\n"
      "abs: ${oc.select:a.x,0}\n"
      "absent: ${oc.select:a.nope,default}\n"
      "missing: ${oc.select:a.m,9}\n"
      "no_default: ${oc.select:zzz}\n"
      "subtree: ${oc.select:a}\n",
      "sel.yaml");
  EXPECT_EQ(Select(cfg, "a.rel", resolvers).AsInt(), 1);
  EXPECT_EQ(Select(cfg, "abs", resolvers).AsInt(), 1);
  EXPECT_EQ(Select(cfg, "absent", resolvers).AsString(), "default");
  EXPECT_EQ(Select(cfg, "missing", resolvers).AsInt(), 9);
  EXPECT_TRUE(Select(cfg, "no_default", resolvers).IsNull());
  const ConfigNode subtree = Select(cfg, "subtree", resolvers);
  EXPECT_EQ(subtree.at("x").AsInt(), 1);
  EXPECT_TRUE(subtree.at("m").IsMissing());
  EXPECT_EQ(subtree.at("rel").AsInt(), 1);
}

// OmegaConf 2.x usage.rst, "oc.decode": parse environment variables.
TEST(Resolvers, OcDecodeParsesAStringAsAValue) {
  const ResolverRegistry resolvers;
  ::setenv("SOMA_TEST_DB_PORT", "3308", 1);
  ::setenv("SOMA_TEST_DB_NODES", "[host1, host2, host3]", 1);
  ::unsetenv("SOMA_TEST_DB_TIMEOUT");
  const ConfigNode cfg = ParseYaml(
      "x: 7\n"
      "database:\n"
      "  port: ${oc.decode:${oc.env:SOMA_TEST_DB_PORT}}\n"
      "  nodes: ${oc.decode:${oc.env:SOMA_TEST_DB_NODES}}\n"
      "  timeout: ${oc.decode:${oc.env:SOMA_TEST_DB_TIMEOUT,null}}\n"
      "dict: \"${oc.decode:'{a: 1, b: [true, 0.5]}'}\"\n"
      "interp: ${oc.decode:'${x}'}\n"
      "quoted: ${oc.decode:\"'3308'\"}\n"
      "not_str: ${oc.decode:5}\n"
      "bad: ${oc.decode:'[1, 2'}\n",
      "decode.yaml");
  const ConfigNode port = Select(cfg, "database.port", resolvers);
  ASSERT_TRUE(port.IsInt());
  EXPECT_EQ(port.AsInt(), 3308);
  const ConfigNode nodes = Select(cfg, "database.nodes", resolvers);
  ASSERT_TRUE(nodes.IsList());
  ASSERT_EQ(nodes.size(), 3u);
  EXPECT_EQ(nodes.items()[2].AsString(), "host3");
  EXPECT_TRUE(Select(cfg, "database.timeout", resolvers).IsNull());
  const ConfigNode dict = Select(cfg, "dict", resolvers);
  EXPECT_EQ(dict.at("a").AsInt(), 1);
  EXPECT_TRUE(dict.at("b").items()[0].AsBool());
  EXPECT_EQ(dict.at("b").items()[1].AsDouble(), 0.5);
  EXPECT_EQ(Select(cfg, "interp", resolvers).AsInt(), 7);
  const ConfigNode quoted = Select(cfg, "quoted", resolvers);
  ASSERT_TRUE(quoted.IsString());
  EXPECT_EQ(quoted.AsString(), "3308");
  EXPECT_NE(
      ErrorMessage<ConfigError>([&] { Select(cfg, "not_str", resolvers); })
          .find("`oc.decode` can only take strings or None as input, but "
                "`5` is of type int"),
      std::string::npos);
  EXPECT_NE(ErrorMessage<ConfigError>([&] {
              Select(cfg, "bad", resolvers);
            }).find("GrammarParseError"),
            std::string::npos);
}

// OmegaConf 2.x usage.rst, "oc.create".
TEST(Resolvers, OcCreateMakesConfigNodes) {
  const ResolverRegistry resolvers;
  ::setenv("SOMA_TEST_YAML_ENV", "A: 10\nb: 20\nc: ${x}\n", 1);
  const ConfigNode cfg = ParseYaml(
      "x: 3\n"
      "plain_dict: {a: 1}\n"
      "dict_config: \"${oc.create:{a: 1}}\"\n"
      "list_config: ${oc.create:[1, '${x}']}\n"
      "dict_config_env: ${oc.create:${oc.env:SOMA_TEST_YAML_ENV}}\n"
      "from_null: ${oc.create:null}\n"
      "bad: ${oc.create:5}\n",
      "create.yaml");
  const ConfigNode dict = Select(cfg, "dict_config", resolvers);
  ASSERT_TRUE(dict.IsMap());
  EXPECT_EQ(dict.at("a").AsInt(), 1);
  const ConfigNode list = Select(cfg, "list_config", resolvers);
  ASSERT_TRUE(list.IsList());
  EXPECT_EQ(list.items()[1].AsString(), "3");
  const ConfigNode from_env = Select(cfg, "dict_config_env", resolvers);
  ASSERT_TRUE(from_env.IsMap());
  EXPECT_EQ(from_env.at("A").AsInt(), 10);
  EXPECT_EQ(from_env.at("b").AsInt(), 20);
  EXPECT_EQ(from_env.at("c").AsInt(), 3);
  const ConfigNode empty = Select(cfg, "from_null", resolvers);
  ASSERT_TRUE(empty.IsMap());
  EXPECT_EQ(empty.size(), 0u);
  EXPECT_NE(ErrorMessage<ConfigError>([&] {
              Select(cfg, "bad", resolvers);
            }).find("Object of unsupported type: 'int'"),
            std::string::npos);
}

// OmegaConf 2.x usage.rst, "oc.deprecated".
TEST(Resolvers, OcDeprecatedReturnsTheNewKey) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "new_key: 10\n"
      "old_key: ${oc.deprecated:new_key}\n"
      "custom: ${oc.deprecated:new_key,'$OLD_KEY is old, use $NEW_KEY'}\n"
      "sub:\n  v: [0, 1]\n  old: ${oc.deprecated:.v}\n"
      "gone: ${oc.deprecated:z}\n"
      "int_key: ${oc.deprecated:111111}\n"
      "int_message: ${oc.deprecated:new_key,1000}\n",
      "deprecated.yaml");
  const ConfigNode value = Select(cfg, "old_key", resolvers);
  ASSERT_TRUE(value.IsInt());
  EXPECT_EQ(value.AsInt(), 10);
  EXPECT_EQ(Select(cfg, "custom", resolvers).AsInt(), 10);
  EXPECT_EQ(Select(cfg, "sub.old", resolvers).items()[1].AsInt(), 1);
  // OmegaConf's test_deprecated_target_not_found wording.
  EXPECT_NE(ErrorMessage<ConfigError>([&] {
              Select(cfg, "gone", resolvers);
            }).find("In oc.deprecated resolver at 'gone': Key not found: 'z'"),
            std::string::npos);
  EXPECT_NE(
      ErrorMessage<ConfigError>([&] { Select(cfg, "int_key", resolvers); })
          .find("oc.deprecated: interpolation key type is not a string "
                "(int)"),
      std::string::npos);
  EXPECT_NE(
      ErrorMessage<ConfigError>([&] { Select(cfg, "int_message", resolvers); })
          .find("oc.deprecated: interpolation message type is not a "
                "string (int)"),
      std::string::npos);
}

// OmegaConf 2.x usage.rst, "Extracting lists of keys / values from a
// dictionary".
TEST(Resolvers, OcDictKeysAndValues) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "ip7: 10.0.0.9\n"
      "workers:\n"
      "  node3: 10.0.0.2\n"
      "  node7: ${ip7}\n"
      "nodes: \"${oc.dict.keys: workers}\"\n"
      "ips: \"${oc.dict.values: workers}\"\n"
      "sub:\n  d: {a: 1, b: 2}\n  rel: ${oc.dict.values:.d}\n"
      "lst: [1, 2]\n"
      "on_list: ${oc.dict.keys:lst}\n"
      "absent: ${oc.dict.values:nope}\n"
      "not_str: ${oc.dict.keys:5}\n",
      "dict.yaml");
  const ConfigNode nodes = Select(cfg, "nodes", resolvers);
  ASSERT_TRUE(nodes.IsList());
  ASSERT_EQ(nodes.size(), 2u);
  EXPECT_EQ(nodes.items()[0].AsString(), "node3");
  EXPECT_EQ(nodes.items()[1].AsString(), "node7");
  const ConfigNode ips = Select(cfg, "ips", resolvers);
  ASSERT_EQ(ips.size(), 2u);
  EXPECT_EQ(ips.items()[0].AsString(), "10.0.0.2");
  EXPECT_EQ(ips.items()[1].AsString(), "10.0.0.9");
  const ConfigNode rel = Select(cfg, "sub.rel", resolvers);
  ASSERT_EQ(rel.size(), 2u);
  EXPECT_EQ(rel.items()[1].AsInt(), 2);
  EXPECT_NE(
      ErrorMessage<ConfigError>([&] { Select(cfg, "on_list", resolvers); })
          .find("`oc.dict.keys` cannot be applied to objects of type: "
                "ListConfig"),
      std::string::npos);
  EXPECT_NE(ErrorMessage<ConfigError>([&] {
              Select(cfg, "absent", resolvers);
            }).find("Key not found: 'nope'"),
            std::string::npos);
  EXPECT_NE(
      ErrorMessage<ConfigError>([&] { Select(cfg, "not_str", resolvers); })
          .find("`oc.dict.keys` requires a string as input, but obtained "
                "`5` of type: int"),
      std::string::npos);
}

TEST(Resolvers, HydraReadsTheHydraNode) {
  const ResolverRegistry resolvers;
  const ConfigNode cfg = ParseYaml(
      "hydra:\n"
      "  runtime:\n"
      "    output_dir: /tmp/out\n"
      "  job:\n"
      "    name: train\n"
      "    num: 3\n"
      "out: ${hydra:runtime.output_dir}/model.pt\n"
      "num: ${hydra:job.num}\n"
      "bad: ${hydra:job.nope}\n",
      "h.yaml");
  EXPECT_EQ(Select(cfg, "out", resolvers).AsString(), "/tmp/out/model.pt");
  EXPECT_EQ(Select(cfg, "num", resolvers).AsInt(), 3);
  EXPECT_THROW(Select(cfg, "bad", resolvers), InterpolationKeyError);

  const ConfigNode no_hydra = ParseYaml("out: ${hydra:job.name}\n", "n.yaml");
  const std::string message =
      ErrorMessage<ConfigError>([&] { Select(no_hydra, "out", resolvers); });
  EXPECT_NE(message.find("hydra"), std::string::npos) << message;
}

const char* const kOverrideDirnameYaml = R"(hydra:
  overrides:
    task: [learning_rate=0.01, seed=1, batch_size=32]
  job:
    config:
      override_dirname:
        kv_sep: '='
        item_sep: ','
        exclude_keys: [seed]
  sweep:
    dir: multirun
    subdir: ${hydra_override_dirname:}/seed=${seed}
seed: 1
dir: ${hydra:job.override_dirname}
)";

TEST(Resolvers, HydraOverrideDirname) {
  const ResolverRegistry resolvers;
  ConfigNode cfg = ParseYaml(kOverrideDirnameYaml, "od.yaml");
  EXPECT_EQ(Select(cfg, "hydra.sweep.subdir", resolvers).AsString(),
            "batch_size=32,learning_rate=0.01/seed=1");
  EXPECT_EQ(Select(cfg, "dir", resolvers).AsString(),
            "batch_size=32,learning_rate=0.01");

  cfg.SetPath("hydra.job.config.override_dirname.kv_sep", "_");
  cfg.SetPath("hydra.job.config.override_dirname.item_sep", "/");
  cfg.SetPath("hydra.overrides.task[0]", "+learning_rate=a=b");
  EXPECT_EQ(Select(cfg, "dir", resolvers).AsString(),
            "+learning_rate_a=b/batch_size_32");

  // Defaults: '=' and ',' with nothing excluded.
  ConfigNode bare;
  bare.SetPath("hydra.overrides.task", ConfigNode::EmptyList());
  bare.at("hydra").at("overrides").at("task").Append("b=2");
  bare.at("hydra").at("overrides").at("task").Append("a=1");
  bare.Set("d", "${hydra_override_dirname:}");
  EXPECT_EQ(Select(bare, "d", resolvers).AsString(), "a=1,b=2");

  // A stored hydra.job.override_dirname wins.
  bare.SetPath("hydra.job.override_dirname", "stored");
  bare.Set("e", "${hydra:job.override_dirname}");
  EXPECT_EQ(Select(bare, "e", resolvers).AsString(), "stored");
}

TEST(Resolvers, ResolverCanSelectFromTheSameTree) {
  ResolverRegistry resolvers;
  resolvers.Register(
      "lookup",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        return Select(*call.root, args.at(0).AsString(), *call.registry);
      });
  const ConfigNode cfg =
      ParseYaml("a: 1\nb: ${lookup:a}\nc: ${lookup:c}\n", "l.yaml");
  EXPECT_EQ(Select(cfg, "b", resolvers).AsInt(), 1);
  EXPECT_EQ(ErrorMessage<ConfigError>([&] { Select(cfg, "c", resolvers); }),
            "InterpolationResolutionError: Recursive interpolation detected. "
            "Interpolation cycle: c -> c");
}

TEST(Resolvers, RegistryBasics) {
  ResolverRegistry resolvers;
  for (const char* name :
       {"now", "oc.env", "oc.select", "hydra", "hydra_override_dirname"}) {
    EXPECT_TRUE(resolvers.Has(name)) << name;
  }
  const std::vector<std::string> names = resolvers.Names();
  EXPECT_TRUE(std::is_sorted(names.begin(), names.end()));
  EXPECT_THROW(
      resolvers.Register("now",
                         [](const std::vector<ConfigNode>&,
                            const ResolverCall&) { return ConfigNode(); }),
      ConfigError);
  EXPECT_TRUE(DefaultResolvers().Has("oc.env"));
  EXPECT_EQ(&DefaultResolvers(), &DefaultResolvers());
}

}  // namespace
}  // namespace soma
