// ConfigSchema (common/, the one engine of the drive, plant and scenario files): every error
// class names the file, the line and the key; values land in the struct; defaults stay where
// no key is given.
#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <toml++/toml.h>

#include "config_schema.hpp"
#include "key_rules.hpp"

namespace pmsm::common {
namespace {

struct Demo {
  double gain = 1.5;
  int count = 3;
  bool on = false;
  std::string name = "x";
  int mode = 0;
  std::vector<double> levels{1.0};
  double ratio = 0.5;
};

const ConfigSchema<Demo>& demo_schema() {
  static const ConfigSchema<Demo> s = [] {
    ConfigSchema<Demo> d;
    d.real("motor.gain", [](Demo& c) -> double& { return c.gain; }, positive(10.0), "V", "A gain.");
    d.integer("motor.count", [](Demo& c) -> int& { return c.count; }, between(1, 8), "A count.");
    d.boolean("motor.on", [](Demo& c) -> bool& { return c.on; }, "A switch.");
    d.string("motor.name", [](Demo& c) -> std::string& { return c.name; }, "A name.");
    d.choice("control.mode", {{"speed", 0}, {"torque", 1}}, [](const Demo& c) { return c.mode; },
             [](Demo& c, int v) { c.mode = v; }, "A mode.");
    d.list("control.levels", 1, 3, between(0.05, 1.0), [](const Demo& c) { return c.levels; },
           [](Demo& c, const std::vector<double>& v) { c.levels = v; }, "", "Levels.");
    d.real("ratio", [](Demo& c) -> double& { return c.ratio; }, between(0.0, 1.0), "", "A top-level ratio.");
    return d;
  }();
  return s;
}

Demo parse_demo(std::string_view text, const std::vector<std::string>& foreign = {}, std::string_view prefix = {}) {
  const toml::table t = toml::parse(text, std::string_view{"demo.toml"});
  Demo d;
  demo_schema().apply(t, d, "fallback.toml", foreign, prefix);
  return d;
}

// The message of the ConfigError that parsing `text` throws ("" when none).
std::string error_of(std::string_view text, std::string_view prefix = {}) {
  try {
    (void)parse_demo(text, {}, prefix);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(ConfigSchema, AppliesEveryKindOfValue) {
  const Demo d = parse_demo(R"(ratio = 0.25
[motor]
gain = 2          # an integer is a fine real
count = 8
on = true
name = "left"
[control]
mode = "torque"
levels = [1.0, 0.4, 0.05]
)");
  EXPECT_EQ(d.gain, 2.0);
  EXPECT_EQ(d.count, 8);
  EXPECT_TRUE(d.on);
  EXPECT_EQ(d.name, "left");
  EXPECT_EQ(d.mode, 1);
  EXPECT_EQ(d.levels, (std::vector<double>{1.0, 0.4, 0.05}));
  EXPECT_EQ(d.ratio, 0.25);
}

TEST(ConfigSchema, AbsentKeysKeepTheirDefaults) {
  const Demo d = parse_demo("[motor]\ncount = 2\n");
  const Demo defaults;
  EXPECT_EQ(d.count, 2);
  EXPECT_EQ(d.gain, defaults.gain);
  EXPECT_EQ(d.on, defaults.on);
  EXPECT_EQ(d.name, defaults.name);
  EXPECT_EQ(d.levels, defaults.levels);
  EXPECT_EQ(d.ratio, defaults.ratio);
}

TEST(ConfigSchema, DottedKeysAndInlineTablesAreTheSameKeys) {
  EXPECT_EQ(parse_demo("motor.gain = 3.5\n").gain, 3.5);
  EXPECT_EQ(parse_demo("motor = { gain = 4.5 }\n").gain, 4.5);
}

// A NUL in a path cut it where the system read it (the daemon read another file than the one
// named, and an error message lost its reason); a newline split a report's line. Any control
// character in a string is refused, named with its position.
TEST(ConfigSchema, AStringWithAControlCharacterIsRefused) {
  EXPECT_EQ(error_of("[motor]\nname = \"a\\u0000.toml\"\n"), "demo.toml:2: motor.name: contains a control character (U+0000) at position 2");
  EXPECT_EQ(error_of("[motor]\nname = \"two\\nlines\"\n"), "demo.toml:2: motor.name: contains a control character (U+000A) at position 4");
  EXPECT_EQ(parse_demo("[motor]\nname = \"it's \\\"fine\\\"\"\n").name, "it's \"fine\"");
}

TEST(ConfigSchema, UnknownKeyNamesFileLineKeyAndSuggests) {
  EXPECT_EQ(error_of("[motor]\ngain = 2\ngian = 3\n"), "demo.toml:3: motor.gian: unknown key (did you mean motor.gain?)");
  // Nothing close: no suggestion.
  EXPECT_EQ(error_of("[motor]\nzzzzzzzzzz = 1\n"), "demo.toml:2: motor.zzzzzzzzzz: unknown key");
  // An unknown section is an unknown key at its header.
  EXPECT_EQ(error_of("\n[motr]\ngain = 1\n"), "demo.toml:2: motr: unknown key (did you mean [motor]?)");
  EXPECT_EQ(error_of("rato = 0.3\n"), "demo.toml:1: rato: unknown key (did you mean ratio?)");
}

TEST(ConfigSchema, ASectionGivenAsAValue) {
  EXPECT_EQ(error_of("\nmotor = 3\n"), "demo.toml:2: motor: expected a table (section)");
}

TEST(ConfigSchema, WrongTypesNameTheExpectedAndTheGivenType) {
  EXPECT_EQ(error_of("[motor]\ngain = \"big\"\n"), "demo.toml:2: motor.gain: expected a number, got a string");
  EXPECT_EQ(error_of("[motor]\n\ncount = 2.5\n"), "demo.toml:3: motor.count: expected an integer, got a number");
  EXPECT_EQ(error_of("[motor]\non = 1\n"), "demo.toml:2: motor.on: expected true or false, got an integer");
  EXPECT_EQ(error_of("[motor]\nname = 7\n"), "demo.toml:2: motor.name: expected a string, got an integer");
  EXPECT_EQ(error_of("[control]\nlevels = 0.5\n"), "demo.toml:2: control.levels: expected an array of numbers, got a number");
  EXPECT_EQ(error_of("[motor]\ngain = [1]\n"), "demo.toml:2: motor.gain: expected a number, got an array");
  EXPECT_EQ(error_of("[motor]\ngain = 1979-05-27\n"), "demo.toml:2: motor.gain: expected a number, got a date or time");
}

TEST(ConfigSchema, OutOfRangeNamesTheRangeAndTheValue) {
  // positive(10): open at 0, closed at 10.
  EXPECT_EQ(error_of("[motor]\ngain = 0\n"), "demo.toml:2: motor.gain: must be in (0, 10], got 0");
  EXPECT_EQ(error_of("[motor]\ngain = 10.5\n"), "demo.toml:2: motor.gain: must be in (0, 10], got 10.5");
  EXPECT_EQ(parse_demo("[motor]\ngain = 10\n").gain, 10.0);
  EXPECT_EQ(parse_demo("[motor]\ngain = 1e-300\n").gain, 1e-300);
  EXPECT_EQ(error_of("[motor]\ncount = 9\n"), "demo.toml:2: motor.count: must be in [1, 8], got 9");
  EXPECT_EQ(error_of("[motor]\ncount = 0\n"), "demo.toml:2: motor.count: must be in [1, 8], got 0");
  EXPECT_EQ(parse_demo("[motor]\ncount = 1\n").count, 1);
  // Not-a-number and infinity are never in range.
  EXPECT_EQ(error_of("[motor]\ngain = nan\n"), "demo.toml:2: motor.gain: must be in (0, 10], got nan");
  EXPECT_EQ(error_of("ratio = -inf\n"), "demo.toml:1: ratio: must be in [0, 1], got -inf");
}

TEST(ConfigSchema, ListLengthAndElements) {
  EXPECT_EQ(error_of("[control]\nlevels = [1.0, 0.8, 0.6, 0.4]\n"), "demo.toml:2: control.levels: expected 1 to 3 values, got 4");
  EXPECT_EQ(error_of("[control]\nlevels = []\n"), "demo.toml:2: control.levels: expected 1 to 3 values, got 0");
  EXPECT_EQ(error_of("[control]\nlevels = [1.0, 2.0]\n"), "demo.toml:2: control.levels: every value must be in [0.05, 1], got 2");
  // A non-number element is reported at its own line.
  EXPECT_EQ(error_of("[control]\nlevels = [\n  1.0,\n  \"half\",\n]\n"), "demo.toml:4: control.levels: expected a number, got a string");
}

TEST(ConfigSchema, BadChoiceListsTheChoices) {
  EXPECT_EQ(error_of("[control]\nmode = \"position\"\n"),
            "demo.toml:2: control.mode: expected one of \"speed\", \"torque\", got \"position\"");
  EXPECT_EQ(error_of("[control]\nmode = 1\n"), "demo.toml:2: control.mode: expected one of \"speed\", \"torque\", got an integer");
}

TEST(ConfigSchema, ForeignTablesAreLeftAlone) {
  const Demo d = parse_demo("[plant]\nanything = 1\n[plant.motor]\nx = 2\n[motor]\ncount = 4\n", {"plant"});
  EXPECT_EQ(d.count, 4);
  // Without the exemption the same file is an error.
  try {
    (void)parse_demo("[plant]\nanything = 1\n");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), "demo.toml:1: plant: unknown key");
  }
}

TEST(ConfigSchema, KeyPrefixNamesTheKeyAsTheFileNestsIt) {
  EXPECT_EQ(error_of("[motor]\ncount = 12\n", "controller."), "demo.toml:2: controller.motor.count: must be in [1, 8], got 12");
}

TEST(ConfigSchema, SourceNameWhenTheNodeHasNoFile) {
  // A table built in code has no source region: the caller's name, and no line.
  toml::table t;
  t.insert("ratio", 3.0);
  Demo d;
  try {
    demo_schema().apply(t, d, "built.toml");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), "built.toml: ratio: must be in [0, 1], got 3");
  }
}

TEST(ConfigSchema, MarkdownListsEveryKeyWithItsDefault) {
  const std::string md = demo_schema().markdown(Demo{});
  EXPECT_NE(md.find("| `motor.gain` | 1.5 V | in (0, 10] | A gain. |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `motor.count` | 3 | in [1, 8] | A count. |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `motor.on` | false |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `control.mode` | \"speed\" | \"speed\", \"torque\" |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `control.levels` | [1] |"), std::string::npos) << md;
  EXPECT_EQ(demo_schema().keys(),
            (std::vector<std::string>{"motor.gain", "motor.count", "motor.on", "motor.name", "control.mode", "control.levels", "ratio"}));
}

// The kinds the plant's table needs: seeds, optional reals, per-phase triples, integer lists,
// time tables and paths; and range checks on configurations built in code.
struct Plantish {
  std::uint64_t seed = 1;
  std::optional<double> initial_C;
  std::array<double, 3> offset_A{0.1, -0.1, 0.0};
  std::vector<int> orders;
  std::vector<TimePoint> steps;
  std::filesystem::path csv;
};

const ConfigSchema<Plantish>& plantish_schema() {
  static const ConfigSchema<Plantish> s = [] {
    ConfigSchema<Plantish> d;
    d.seed("sim.seed", [](Plantish& c) -> std::uint64_t& { return c.seed; }, "A seed.");
    d.optional_real("thermal.initial_C", [](Plantish& c) -> std::optional<double>& { return c.initial_C; }, between(-50, 250),
                    "C", "ambient", "Start.");
    d.real3("adc.offset_A", [](Plantish& c) -> std::array<double, 3>& { return c.offset_A; }, between(-1, 1), "A", "Offsets.");
    d.int_list("emf.orders", 3, between(5, 99), [](Plantish& c) -> std::vector<int>& { return c.orders; }, "Orders.");
    d.points("load.steps", between(-10, 10), [](Plantish& c) -> std::vector<TimePoint>& { return c.steps; }, "Nm", "Steps.");
    d.path("load.csv", [](Plantish& c) -> std::filesystem::path& { return c.csv; }, "A file.");
    return d;
  }();
  return s;
}

std::string plantish_error(std::string_view text) {
  try {
    Plantish p;
    plantish_schema().apply(toml::parse(text, std::string_view{"p.toml"}), p, "p.toml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// A table whose name is close to a section's is named with it ([cann] for [can]); a file of
// thousands of errors lists twenty and counts the rest; a text longer than any path is refused
// without being repeated (a 10 MB value went whole into the message).
TEST(ConfigSchema, ErrorsStayReadable) {
  EXPECT_NE(error_of("[motr]\ngain = 1.0\n").find("demo.toml:1: motr: unknown key (did you mean [motor]?)"), std::string::npos)
      << error_of("[motr]\ngain = 1.0\n");
  EXPECT_EQ(error_of("[zzzzzz]\ngain = 1.0\n").find("did you mean"), std::string::npos) << "nothing close";
  // Not the parent of a table under it, nor a short name two edits away.
  EXPECT_EQ(error_of("[motor.x]\ngain = 1.0\n").find("did you mean ["), std::string::npos) << error_of("[motor.x]\ngain = 1.0\n");
  EXPECT_EQ(error_of("[mo]\ngain = 1.0\n").find("did you mean ["), std::string::npos) << error_of("[mo]\ngain = 1.0\n");
  // A key from the file is cut in the message.
  EXPECT_LT(error_of("\"" + std::string(100000, 'k') + "\" = 1\n").size(), 200U);
  std::string many;
  for (int k = 0; k < 30; ++k) {
    many += "unknown_" + std::to_string(k) + " = 1\n";
  }
  const std::string listed = error_of(many);
  std::size_t lines = 0;
  for (std::size_t at = listed.find("unknown key"); at != std::string::npos; at = listed.find("unknown key", at + 1)) {
    ++lines;
  }
  EXPECT_EQ(lines, 20U) << listed;
  EXPECT_NE(listed.find("10 more errors not listed"), std::string::npos) << listed;
  const std::string long_name = error_of("[motor]\nname = \"" + std::string(5000, 'a') + "\"\n");
  EXPECT_NE(long_name.find("motor.name: a text of 5000 bytes, at most 4096"), std::string::npos) << long_name.substr(0, 200);
  EXPECT_LT(long_name.size(), 200U);
  EXPECT_LT(error_of("[control]\nmode = \"" + std::string(5000, 'a') + "\"\n").size(), 300U);
}

TEST(ConfigSchema, PlantKindsParse) {
  Plantish p;
  plantish_schema().apply(toml::parse(std::string_view{R"([sim]
seed = 12345678901
[thermal]
initial_C = 40
[adc]
offset_A = [0.2, 0, -0.2]
[emf]
orders = [5, 7]
[load]
steps = [[0, 1.0], [0.5, -2], [0.5, 3]]
csv = "cycle.csv"
)"}, std::string_view{"p.toml"}),
                          p, "p.toml");
  EXPECT_EQ(p.seed, 12345678901U);
  EXPECT_EQ(p.initial_C, 40.0);
  EXPECT_EQ(p.offset_A[2], -0.2);
  EXPECT_EQ(p.orders, (std::vector<int>{5, 7}));
  ASSERT_EQ(p.steps.size(), 3U);
  EXPECT_EQ(p.steps[1].value, -2.0);
  EXPECT_EQ(p.csv, std::filesystem::path("cycle.csv"));
}

TEST(ConfigSchema, PlantKindErrorsNameFileLineAndKey) {
  EXPECT_EQ(plantish_error("[sim]\nseed = -1\n"), "p.toml:2: sim.seed: must be >= 0, got -1");
  EXPECT_EQ(plantish_error("[adc]\noffset_A = [0.1, 0.2]\n"),
            "p.toml:2: adc.offset_A: expected an array of 3 numbers (phases a, b, c), got 2 elements");
  EXPECT_EQ(plantish_error("[adc]\noffset_A = [0.1, 2, 0]\n"), "p.toml:2: adc.offset_A: every value must be in [-1, 1], got 2");
  EXPECT_EQ(plantish_error("[emf]\norders = [5, 7, 11, 13]\n"), "p.toml:2: emf.orders: at most 3 values, got 4");
  EXPECT_EQ(plantish_error("[load]\nsteps = [[1, 0], [0.5, 1]]\n"),
            "p.toml:2: load.steps: element 2 of 2: times must be ascending, got 0.5 after 1");
  EXPECT_EQ(plantish_error("[load]\nsteps = [[0, 20]]\n"), "p.toml:2: load.steps: element 1 of 1: value must be in [-10, 10], got 20");
  EXPECT_EQ(plantish_error("[load]\nsteps = [[0]]\n"), "p.toml:2: load.steps: element 1 of 1: expected [time_s, value]");
  EXPECT_EQ(plantish_error("[load]\ncsv = 3\n"), "p.toml:2: load.csv: expected a file path (string), got an integer");
  EXPECT_EQ(plantish_error("[thermal]\ninitial_C = 300\n"), "p.toml:2: thermal.initial_C: must be in [-50, 250], got 300");
}

TEST(ConfigSchema, ValidateChecksConfigsBuiltInCode) {
  Plantish p;
  EXPECT_NO_THROW(plantish_schema().validate(p, "code"));
  p.offset_A[1] = 5.0;
  try {
    plantish_schema().validate(p, "code");
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), "code: adc.offset_A: must be in [-1, 1], got 5");
  }
}

TEST(ConfigSchema, MarkdownOfThePlantKinds) {
  const std::string md = plantish_schema().markdown(Plantish{});
  EXPECT_NE(md.find("| `thermal.initial_C` | ambient | in [-50, 250] | Start. |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `adc.offset_A` | [0.1, -0.1, 0] A |"), std::string::npos) << md;
  EXPECT_NE(md.find("| `sim.seed` | 1 |"), std::string::npos) << md;
}

TEST(ValueRange, Describe) {
  EXPECT_EQ(positive().describe(), "> 0");
  EXPECT_EQ(at_least(2.0).describe(), ">= 2");
  EXPECT_EQ(between(-1.0, 1.0).describe(), "in [-1, 1]");
  EXPECT_EQ(ValueRange{}.describe(), "a finite number");  // NaN and inf never pass
  EXPECT_FALSE(positive().contains(0.0));
  EXPECT_TRUE(positive().contains(1e-300));
  EXPECT_TRUE(at_least(2.0).contains(2.0));
}

}  // namespace
}  // namespace pmsm::common

namespace pmsm::common {
namespace {

std::string dotted(std::size_t segments, std::string_view sep = ".") {
  std::string key = "x";
  for (std::size_t k = 1; k < segments; ++k) {
    key += sep;
    key += "x";
  }
  return key;
}

// toml++ builds a dotted key's tables by recursion: a header of 50,000 segments (100 KB)
// overflowed the stack in every reader (SIGSEGV, no message). It is refused before parsing,
// named by file and line.
TEST(TomlDepth, ADeepKeyIsRefusedBeforeTheParserRecursesIntoIt) {
  for (const std::string& text : {"a = 1\n[" + dotted(50000) + "]\n", "a = 1\n" + dotted(50000) + " = 1\n",
                                  "a = 1\n[[" + dotted(50000) + "]]\n", "a = 1\nt = { " + dotted(50000, " . ") + " = 1 }\n",
                                  "a = 1\n[" + dotted(50000, ".\"q.r\".") + "]\n"}) {
    try {
      (void)parse_toml(text, "deep.toml");
      ADD_FAILURE() << "accepted: " << text.substr(0, 40);
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("deep.toml:2: a key or table header nested more than 64 levels deep"),
                std::string::npos)
          << e.what();
    }
  }
  EXPECT_TRUE(toml_key_depth_problem("[" + dotted(kMaxTomlKeyDepth) + "]\n") == std::nullopt) << "the limit itself";
  EXPECT_TRUE(toml_key_depth_problem("[" + dotted(kMaxTomlKeyDepth + 1) + "]\n").has_value());
}

// What is no key is not counted: strings (one line or many, with escapes), comments, arrays of
// floats, dates.
TEST(TomlDepth, StringsCommentsNumbersAndDatesAreNoKeys) {
  const std::string dots(5000, '.');
  std::string floats = "v = [";
  for (int k = 0; k < 5000; ++k) {
    floats += "1.5e-3, ";
  }
  floats += "2.0]\n";
  for (const std::string& text :
       {"s = \"" + dots + "\"\n", "s = '" + dots + "'\n", "s = \"\"\"\n" + dots + "\n" + dots + "\n\"\"\"\n",
        "s = '''\n" + dots + "\n'''\n", "s = \"a\\\"" + dots + "\"\n", "# " + dots + "\n", floats,
        std::string("d = 1979-05-27T07:32:00.999Z\n"), "[a.\"" + dots + "\".b]\nx = 1\n"}) {
    EXPECT_TRUE(toml_key_depth_problem(text) == std::nullopt) << text.substr(0, 60);
    EXPECT_NO_THROW((void)parse_toml(text, "ok.toml")) << text.substr(0, 60);
  }
  // Lines are counted through multi-line strings.
  const auto p = toml_key_depth_problem("s = \"\"\"\n\n\n\"\"\"\n" + dotted(100) + " = 1\n");
  ASSERT_TRUE(p.has_value());
  EXPECT_EQ(p->line, 5U);
}

// A rule between keys is located at the first of them the file gives, and names each key with
// its value and where it comes from: the line of another given key, or its default (and how).
TEST(KeyRules, LocatedAtTheFirstGivenKeyNamingEveryValuesSource) {
  const toml::table root = parse_toml("[a]\nx = 1\n[b]\ny = 2\n", "f.toml");
  KeyRules rules(root, "f.toml");
  EXPECT_FALSE(rules.any());
  const auto text = [](const auto& value) {
    return value("c.z", 3.0, "V", "twice a.x") + " and " + value("b.y", 2.0, "") + " and " + value("a.x", 1.0, "A");
  };
  rules.with({"c.z", "b.y", "a.x"}, text);  // c.z absent: located at b.y, the first given
  rules.with({"c.z", "c.w"}, text);          // none given: at the file
  rules.append("");                          // nothing
  rules.append("g.toml:9: another check's line");
  rules.at("a.x", "a.x: wrong");
  EXPECT_EQ(rules.errors(),
            "f.toml:4: c.z (3 V, its default: twice a.x) and b.y (2) and a.x (1 A, f.toml:2)\n"
            "f.toml: c.z (3 V, its default: twice a.x) and b.y (2, f.toml:4) and a.x (1 A, f.toml:2)\n"
            "g.toml:9: another check's line\n"
            "f.toml:2: a.x: wrong");
  EXPECT_EQ(KeyRules::location_of_first(root, {"c.z", "a.x"}, "f.toml"), "f.toml:2: ");
  EXPECT_EQ(KeyRules::location_of_first(root, {"c.z"}, "f.toml"), "f.toml: ");
  EXPECT_EQ(KeyRules::first_given(root, {"c.z", "b.y", "a.x"}), "b.y");
}

}  // namespace
}  // namespace pmsm::common
