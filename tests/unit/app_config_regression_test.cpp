// Regression tests: behaviour the headers promise that an earlier version of the scenario and configuration code did not
// deliver (each test says what went wrong then). They guard the fixes.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "config_schema.hpp"
#include "controller_config.hpp"
#include "app_config_test_support.hpp"
#include "scenario.hpp"

namespace pmsm::app {
namespace {

using test::error_of;
using test::inline_error;
using test::path_of;
const std::filesystem::path& kDir = test::kConfigDir;

// ISSUE scenario-points-file: read_points() names the scenario's own path with the line of a
// node that came from the base file.
TEST(RegressionScenario, BadPointsInTheBaseNameTheBaseFile) {
  const std::string e = error_of([] { (void)load_scenario(kDir / "scenario_child_of_bad_points.toml"); });
  EXPECT_EQ(e.rfind(path_of("scenario_bad_points_base.toml") + ":5: operation.speed_rad_s: point 2: times must ascend", 0), 0U) << e;
}

// ISSUE scenario-profile-csv-dir: a plant profile's relative load.csv_path is checked against
// the profile's directory, then loaded against the scenario's directory.
TEST(RegressionScenario, ProfileCsvIsRelativeToTheProfile) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[plant]\nprofile = \"sub/profile_with_cycle.toml\"\n"), "");
}

// ISSUE scenario-plant-unknown-section: an unknown section among the plant overrides is
// reported at a line of the re-serialised merged table ("inline.toml [plant]:N: motr: ...").
TEST(RegressionScenario, UnknownPlantSectionInAnOverrideNamesTheScenarioLine) {
  const std::string e = inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n\n[plant.motr]\nrs_ohm = 0.2\n");
  EXPECT_EQ(e.rfind(path_of("inline.toml") + ":4: plant.motr:", 0), 0U) << e;
}

// ISSUE scenario-ambient-profile: the flat list t0, C0, t1, C1, ... accepts an odd count
// (the last value is dropped silently) and times that do not ascend (Profile::at assumes
// they do).
TEST(RegressionScenario, AmbientProfileMustBePairsInAscendingTime) {
  EXPECT_NE(inline_error("[scenario]\nambient_profile = [0, 25, 100]\n[operation]\nspeed_rad_s = [[0, 1]]\n"), "");
  EXPECT_NE(inline_error("[scenario]\nambient_profile = [100, 25, 0, 40]\n[operation]\nspeed_rad_s = [[0, 1]]\n"), "");
}

// ISSUE scenario-csv-location: a CSV that cannot be opened is reported without the scenario
// file or line ("operation.speed_csv: cannot open ...").
TEST(RegressionScenario, MissingCsvNamesTheScenarioFile) {
  const std::string e = inline_error("[operation]\nspeed_csv = \"no_such.csv\"\n");
  EXPECT_EQ(e.rfind(path_of("inline.toml") + ":2: operation.speed_csv:", 0), 0U) << e;
}

// ISSUE scenario-csv-type: operation.speed_csv / torque_csv / scenario.seed of the wrong type
// are ignored silently (they are exempt from the schema and read with value<T>()).
TEST(RegressionScenario, WrongTypeOfCsvKeyIsAnError) {
  const std::string e = inline_error("[operation]\nspeed_rad_s = [[0, 1]]\nspeed_csv = 5\n");
  EXPECT_EQ(e.rfind(path_of("inline.toml") + ":3: operation.speed_csv:", 0), 0U) << e;
  const std::string seed = inline_error("[scenario]\nseed = \"seven\"\n[operation]\nspeed_rad_s = [[0, 1]]\n");
  EXPECT_EQ(seed.rfind(path_of("inline.toml") + ":2: scenario.seed:", 0), 0U) << seed;
}

// ISSUE schema-suggestion-prefix (minor): under a key prefix the suggestion omits it:
// "controller.injection.F_AA: unknown key (did you mean injection.F_A?)".
TEST(RegressionScenario, SuggestionCarriesThePrefix) {
  const std::string e = inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.injection]\nF_AA = 2\n");
  EXPECT_NE(e.find("(did you mean controller.injection.F_A?)"), std::string::npos) << e;
}

// ISSUE config-level-below-fmin: finalize() checks F_min <= F but not F_min <= F x level, so
// levels = [1.0, 0.1] with F = 25 A, F_min = 5 A is accepted and its second pair is skipped at
// every event (reported as a torque-disturbance skip, see the scheduler issue).
TEST(RegressionControllerConfig, EveryLevelMustReachFmin) {
  std::string message;
  try {
    (void)parse_controller_config(toml::parse(std::string_view{"[injection]\nlevels = [1.0, 0.1]\n"}, std::string_view{"drive.toml"}),
                                  "drive.toml", {});
  } catch (const ConfigError& e) {
    message = e.what();
  }
  EXPECT_NE(message.find("injection.levels"), std::string::npos) << message;
}

}  // namespace
}  // namespace pmsm::app
