// Scenario files: base inheritance, plant profiles with overrides, CSV set-points, Profile,
// and error messages that point at the right file, line and key.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "config_schema.hpp"
#include "app_config_test_support.hpp"
#include "drive_node.hpp"
#include "scenario.hpp"
#include "scratch_dir.hpp"

namespace pmsm::app {
namespace {

using test::error_of;
using test::path_of;
const std::filesystem::path& kDir = test::kConfigDir;

// Parses inline text as if it were the file `name` in the fixture directory (so relative
// paths resolve there).
Scenario parse(std::string_view text, const std::string& name = "inline.toml") {
  return parse_scenario(text, kDir / name);
}

std::string inline_error(std::string_view text) { return test::inline_error(text); }

constexpr std::string_view kMinimal = R"([operation]
speed_rad_s = [[0.0, 100.0]]
)";

TEST(Scenario, MinimalScenarioTakesTheDefaults) {
  const Scenario s = parse(kMinimal);
  const ScenarioConfig defaults;
  EXPECT_EQ(s.scenario.name, defaults.name);
  EXPECT_EQ(s.scenario.duration_s, defaults.duration_s);
  EXPECT_EQ(s.scenario.mode, core::DriveMode::kSpeed);
  ASSERT_EQ(s.scenario.speed_rad_s.points.size(), 1U);
  EXPECT_EQ(s.scenario.speed_rad_s.at(3.0), 100.0);
  // The plant is the reference profile (PlantConfig defaults) at the scenario's ambient.
  EXPECT_EQ(s.plant.motor.rs_ohm, plant::PlantConfig{}.motor.rs_ohm);
  EXPECT_EQ(s.plant.thermal.ambient_C, 25.0);
  // The controller is the default controller.
  EXPECT_EQ(controller_schema().markdown(s.controller), controller_schema().markdown(default_controller_config()));
  EXPECT_EQ(s.source, kDir / "inline.toml");
}

// The drive steps once per plant sample: its period is the plant's PWM period.
TEST(Scenario, ControlPeriodMustBeThePlantsPwmPeriod) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.control]\nperiod_s = 5.0e-5\n"),
            path_of("inline.toml") +
                ":4: controller.control.period_s: must be the plant's PWM period, 1 / plant.inverter.pwm_frequency_Hz "
                "= 0.0001 s (the drive steps once per plant sample), got 5e-05 s");
  // Said by the plant's side alone, the controller's default is the one named.
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[plant.inverter]\npwm_frequency_Hz = 20000.0\n"),
            path_of("inline.toml") +
                ": controller.control.period_s: must be the plant's PWM period, 1 / plant.inverter.pwm_frequency_Hz "
                "= 5e-05 s (the drive steps once per plant sample), got 0.0001 s");
  // Both together: accepted.
  const Scenario s = parse("[operation]\nspeed_rad_s = [[0, 1]]\n[plant.inverter]\npwm_frequency_Hz = 20000.0\n"
                           "[controller.control]\nperiod_s = 5.0e-5\n");
  EXPECT_EQ(s.controller.drive.period_s, 5.0e-5);
  // A period that is no exact decimal: seven digits are enough, and a refused one is printed
  // with the digits that tell it from the plant's (six made both read 8.33333e-05).
  EXPECT_NO_THROW((void)parse("[operation]\nspeed_rad_s = [[0, 1]]\n[plant.inverter]\npwm_frequency_Hz = 12000.0\n"
                              "[controller.control]\nperiod_s = 8.333333e-5\n"));
  EXPECT_NE(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[plant.inverter]\npwm_frequency_Hz = 12000.0\n"
                         "[controller.control]\nperiod_s = 8.33e-5\n")
                .find("= 8.333333333e-05 s (the drive steps once per plant sample), got 8.33e-05 s"),
            std::string::npos);
}

// simulate's supervisor trips OVERSPEED at 1.5 x the rated speed by default (the daemon's): a
// speed limit at or above it was accepted, and a washer's spin tripped on its way to 550 rad/s.
// The rule is the daemon's, worded as the daemon words it, and a scenario may raise the trip.
TEST(Scenario, ASpeedLimitAtTheOverspeedTripIsRefused) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.motor]\nrated_speed_rad_s = 314.0\n"
                         "[controller.control]\nspeed_limit_rad_s = 600.0\n"),
            path_of("inline.toml") +
                ":6: controller.control.speed_limit_rad_s (600 rad/s) must be below supervisor.overspeed_rad_s (471 rad/s, "
                "its default: 1.5 x controller.motor.rated_speed_rad_s): the shaft would trip OVERSPEED before the drive "
                "limits its speed");
  EXPECT_NO_THROW((void)parse("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.motor]\nrated_speed_rad_s = 420.0\n"
                              "[controller.control]\nspeed_limit_rad_s = 600.0\n"));
  const Scenario raised = parse("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.motor]\nrated_speed_rad_s = 314.0\n"
                                "[controller.control]\nspeed_limit_rad_s = 600.0\n[supervisor]\noverspeed_rad_s = 650.0\n");
  EXPECT_EQ(raised.supervisor.overspeed_rad_s, 650.0);
}

// [supervisor]: pmsm-thermald's keys, with its defaults for the scenario's drive where absent.
TEST(Scenario, SupervisorKeysAreTheDaemonsOverTheDrivesDefaults) {
  const Scenario plain = parse(kMinimal);
  const core::SupervisorConfig defaults = default_supervisor_config(plain.controller);
  EXPECT_EQ(plain.supervisor.dc_bus_max_V, defaults.dc_bus_max_V);
  EXPECT_EQ(plain.supervisor.overspeed_rad_s, defaults.overspeed_rad_s);
  EXPECT_EQ(plain.supervisor.command_timeout_s, 0.0) << "a scenario sends no DRIVE_COMMAND";
  // The defaults follow the scenario's drive: its bus, its ADC, its rated speed.
  const Scenario other = parse("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.control]\nnominal_dc_bus_V = 300.0\n");
  EXPECT_EQ(other.supervisor.dc_bus_max_V, 375.0);
  EXPECT_EQ(other.supervisor.dc_bus_min_V, 180.0);
  const Scenario given = parse(std::string(kMinimal) + "[supervisor]\ndc_bus_max_V = 800.0\ntrip_temp_C = 200.0\n"
                                                       "sensor_timeout_periods = 20\n");
  EXPECT_EQ(given.supervisor.dc_bus_max_V, 800.0);
  EXPECT_EQ(given.supervisor.trip_temp_C, 200.0);
  EXPECT_EQ(given.supervisor.sensor_timeout_periods, 20);
  EXPECT_EQ(given.supervisor.dc_bus_min_V, defaults.dc_bus_min_V);
}

TEST(Scenario, SupervisorKeysAreCheckedAsTheDaemonChecksThem) {
  // A key out of its range, an unknown one: named with their lines, both at once.
  const std::string bad = inline_error(std::string(kMinimal) + "[supervisor]\ndc_bus_max_V = -5.0\nover_speed = 1.0\n");
  EXPECT_NE(bad.find(":4: supervisor.dc_bus_max_V: must be in [0, 10000], got -5"), std::string::npos) << bad;
  EXPECT_NE(bad.find(":5: supervisor.over_speed"), std::string::npos) << bad;
  // The command timeout is the daemon's alone.
  const std::string timeout = inline_error(std::string(kMinimal) + "[supervisor]\ncommand_timeout_s = 0.5\n");
  EXPECT_EQ(timeout, path_of("inline.toml") +
                         ":4: supervisor.command_timeout_s: a scenario takes every supervisor.* key of pmsm-thermald but "
                         "this one: its drive gets no DRIVE_COMMAND stream (its set-points are [operation]), so the "
                         "timeout would never be judged; delete the key");
  // A rule between the supervisor's keys and the drive's, located at the supervisor's line.
  const std::string above = inline_error(std::string(kMinimal) + "[supervisor]\ndc_bus_max_V = 1000.0\n");
  EXPECT_NE(above.find(":4: supervisor.dc_bus_max_V (1000 V) must be below controller.sensors.dc_bus_full_scale_V"),
            std::string::npos)
      << above;
  // The section put under [controller], where every other drive key goes: named with where it
  // belongs, beside the file's other mistakes.
  const std::string nested = inline_error(std::string(kMinimal) +
                                          "[controller.supervisor]\ndc_bus_max_V = 760.0\n[controller.motor]\nrs_ohm = -1.0\n");
  EXPECT_NE(nested.find(":3: controller.supervisor: the supervisor's keys are a section of their own at the file's top "
                        "level, [supervisor]"),
            std::string::npos)
      << nested;
  EXPECT_NE(nested.find(":6: controller.motor.rs_ohm"), std::string::npos) << nested;
  EXPECT_EQ(nested.find("unknown key"), std::string::npos) << nested;
  // And one between the supervisor's own keys.
  const std::string window = inline_error(std::string(kMinimal) + "[supervisor]\nambient_min_C = 50.0\nambient_max_C = 40.0\n");
  EXPECT_NE(window.find(":4: supervisor.ambient_min_C (50 C) must be below supervisor.ambient_max_C (40 C, "),
            std::string::npos)
      << window;
}

// Every scenario of the benchmark loads: a rule the loader gains (the daemon's supervisor rules,
// 2026-12-06, refused a Z-axis servo whose default overcurrent trip lay below its current limit)
// is met by the files the figures of docs/accuracy.md come from, not found by the next run.
TEST(Scenario, EveryBenchmarkScenarioLoads) {
  const std::filesystem::path root = std::filesystem::path(PMSM_SOURCE_DIR) / "bench/scenarios";
  std::size_t loaded = 0;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(root)) {
    if (entry.path().extension() != ".toml") {
      continue;
    }
    try {
      (void)load_scenario(entry.path());
      ++loaded;
    } catch (const std::exception& e) {
      ADD_FAILURE() << entry.path() << ": " << e.what();
    }
  }
  EXPECT_GT(loaded, 150U) << "the benchmark's scenarios were not found under " << root;
}

TEST(Scenario, BaseInheritanceOverrideWinsAndBaseKeysStay) {
  const Scenario s = load_scenario(kDir / "scenario_child.toml");
  EXPECT_EQ(s.scenario.name, "child");                // overridden
  EXPECT_EQ(s.scenario.duration_s, 5.0);              // overridden
  EXPECT_EQ(s.scenario.description, "the base");      // kept from the base
  EXPECT_EQ(s.scenario.ambient_C, 30.0);              // kept
  EXPECT_EQ(s.scenario.speed_rad_s.at(0.5), 50.0);    // the base's profile
  EXPECT_EQ(s.controller.drive.injection.f_A, 20.0);  // the child's, in a table the base also has
  EXPECT_EQ(s.controller.drive.injection.level_count, 2);  // the base's, same table
  EXPECT_EQ(s.controller.drive.injection.levels[1], 0.5);
  // Plant: the base's profile, the base's override and the child's override.
  EXPECT_EQ(s.plant.emf.shape, plant::EmfShape::sinusoidal);  // profile
  EXPECT_EQ(s.plant.motor.ld_H, 6.0e-3);                      // profile
  EXPECT_EQ(s.plant.mechanics.viscous_Nm_s_rad, 1.0e-3);      // base override
  EXPECT_EQ(s.plant.motor.rs_ohm, 0.15);                      // child override beats the profile
  EXPECT_EQ(s.plant.thermal.ambient_C, 30.0);                 // the scenario's ambient
}

TEST(Scenario, ErrorInTheBaseNamesTheBaseFile) {
  EXPECT_EQ(error_of([] { (void)load_scenario(kDir / "scenario_child_of_bad.toml"); }),
            path_of("scenario_bad_base.toml") + ":4: scenario.duration_s: must be in [0.1, 1e+06], got -1");
}

// A device or a directory named as a file is refused by name, never read (/dev/zero would be
// read forever).
TEST(Scenario, DevicesAndDirectoriesAreNotConfigurationFiles) {
  EXPECT_EQ(inline_error("[scenario]\nbase = \"/dev/zero\"\n"),
            path_of("inline.toml") + ":2: scenario.base: /dev/zero: scenario: is not a regular file");
  EXPECT_EQ(inline_error("[scenario]\nbase = \"/\"\n"), path_of("inline.toml") + ":2: scenario.base: /: scenario: is a directory");
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[plant]\nprofile = \"nope.toml\"\n"),
            path_of("inline.toml") + ":4: plant.profile: " + path_of("nope.toml") + ": plant profile: no such file");
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"/dev/zero\"\n"),
            path_of("inline.toml") + ":2: operation.speed_csv: /dev/zero: CSV: is not a regular file");
}

// A cycle is named as one, with the files in it; a chain longer than 8 bases (not a cycle) with
// its files and the limit (before, both read "bases nest too deep (a cycle?)", at the ninth file).
TEST(Scenario, BaseCycleIsReported) {
  const std::string e = error_of([] { (void)load_scenario(kDir / "cycle_a.toml"); });
  EXPECT_EQ(e, path_of("cycle_b.toml") + ":2: scenario.base: the bases form a cycle: " + path_of("cycle_a.toml") +
                   " -> " + path_of("cycle_b.toml") + " -> " + path_of("cycle_a.toml"));
}

TEST(Scenario, AChainOfMoreThanEightBasesIsReported) {
  const pmsm::test::ScratchDir scratch{"pmsm-scenario-chain"};
  const std::filesystem::path& dir = scratch.path();
  for (int k = 0; k <= 9; ++k) {
    std::ofstream(dir / ("c" + std::to_string(k) + ".toml"))
        << (k == 0 ? std::string("[scenario]\nduration_s = 1\n")
                   : "[scenario]\nbase = \"c" + std::to_string(k - 1) + ".toml\"\n");
  }
  const std::string e = error_of([&] { (void)load_scenario(dir / "c9.toml"); });
  EXPECT_NE(e.find((dir / "c1.toml").string() + ":2: scenario.base: more than 8 bases in a chain: " +
                   (dir / "c9.toml").string() + " -> "),
            std::string::npos)
      << e;
  // Eight bases are fine (the chain's end is no complete scenario: its own error, not the chain's).
  const std::string eight = error_of([&] { (void)load_scenario(dir / "c8.toml"); });
  EXPECT_EQ(eight.find("bases in a chain"), std::string::npos) << eight;
}

TEST(Scenario, MissingBaseIsReported) {
  const std::string e = inline_error("[scenario]\nbase = \"no_such_base.toml\"\n");
  EXPECT_EQ(e, path_of("inline.toml") + ":2: scenario.base: " + path_of("no_such_base.toml") + ": scenario: no such file");
}

TEST(Scenario, ErrorsInTheScenarioNameFileLineAndKey) {
  EXPECT_EQ(inline_error("[scenario]\nname = \"x\"\nduration_s = -1\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":3: scenario.duration_s: must be in [0.1, 1e+06], got -1");
  EXPECT_EQ(inline_error("[scenario]\ndurations = 3\n"),
            path_of("inline.toml") + ":2: scenario.durations: unknown key (did you mean scenario.duration_s?)");
  EXPECT_EQ(inline_error("[operation]\nmode = \"position\"\n"),
            path_of("inline.toml") + ":2: operation.mode: expected one of \"speed\", \"torque\", got \"position\"");
  // Set-point profiles.
  EXPECT_EQ(inline_error("[operation]\n\nspeed_rad_s = [[0, 1], [0, 2]]\n"),
            path_of("inline.toml") + ":3: operation.speed_rad_s: point 1: times must ascend (0 after 0)");
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1, 2]]\n"),
            path_of("inline.toml") + ":2: operation.speed_rad_s: point 0: every point must be [time_s, value]");
  // NaN, inf and values beyond what a supervisor may command are refused by name.
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 0], [1, nan]]\n"),
            path_of("inline.toml") + ":2: operation.speed_rad_s: point 1: value must be a number in [-2000, 2000] rad/s, got nan");
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 0], [inf, 5]]\n"),
            path_of("inline.toml") + ":2: operation.speed_rad_s: point 1: time must be a number in [0, 1e6] s, got inf");
  EXPECT_EQ(inline_error("[operation]\nmode = \"torque\"\ntorque_Nm = [[0, 1e9]]\n"),
            path_of("inline.toml") + ":3: operation.torque_Nm: point 0: value must be a number in [-1000, 1000] Nm, got 1e+09");
  EXPECT_EQ(inline_error("[scenario]\nambient_profile = [0.0, 20.0, 10.0, nan]\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":2: scenario.ambient_profile: every value must be in [-1e+06, 1e+06], got nan");
  EXPECT_EQ(inline_error("[scenario]\nambient_profile = [0.0, 20.0, 10.0, 500.0]\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":2: scenario.ambient_profile: every point needs time_s >= 0 and a temperature in [-40, 80] C, got 10, 500");
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = []\n"),
            path_of("inline.toml") + ":2: operation.speed_rad_s: expected a non-empty array of [time_s, value] pairs");
  EXPECT_EQ(inline_error("[scenario]\nname = \"no profile\"\n"),
            path_of("inline.toml") + ": operation.speed_rad_s (or operation.speed_csv) is required in speed mode");
  EXPECT_EQ(inline_error("[operation]\nmode = \"torque\"\n"),
            path_of("inline.toml") + ": operation.torque_Nm (or operation.torque_csv) is required in torque mode");
  EXPECT_EQ(inline_error("[scenario]\nseed = -3\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":2: scenario.seed: expected an integer >= 0");
  // A TOML syntax error names the line.
  EXPECT_EQ(inline_error("[scenario]\nname = \n").rfind(path_of("inline.toml") + ":2: ", 0), 0U)
      << inline_error("[scenario]\nname = \n");
}

// A file with mistakes in several parts names every one, as pmsm-thermald does with its own
// file: the scenario's keys, the plant's and the controller's (only the first was named).
TEST(Scenario, MistakesInEveryPartAreNamedTogether) {
  EXPECT_EQ(inline_error("[scenario]\nduraton_s = 5\n[operation]\nspeed_rad_s = [[0, 0], [1, nan]]\n[plant.motor]\n"
                         "rs_ohm = -1\n[controller.injection]\nF = 3\nF_A = 1e9\n"),
            path_of("inline.toml") + ":2: scenario.duraton_s: unknown key (did you mean scenario.duration_s?)\n" +
                path_of("inline.toml") + ":6: plant.motor.rs_ohm: must be in [1e-06, 100], got -1\n" +
                path_of("inline.toml") + ":8: controller.injection.F: unknown key (did you mean controller.injection.F_A?)\n" +
                path_of("inline.toml") + ":9: controller.injection.F_A: must be in (0, 1000], got 1e+09");
  // The seed and the ambient profile need only the scenario's keys: named beside the plant's.
  EXPECT_EQ(inline_error("[scenario]\nseed = -3\nambient_profile = [0.0, 20.0, 10.0]\n[operation]\nspeed_rad_s = [[0, 1]]\n"
                         "[plant.motor]\nrs_ohm = -1\n"),
            path_of("inline.toml") + ":2: scenario.seed: expected an integer >= 0\n" + path_of("inline.toml") +
                ":3: scenario.ambient_profile: expected pairs of time_s and temperature_C (an even number of values)\n" +
                path_of("inline.toml") + ":7: plant.motor.rs_ohm: must be in [1e-06, 100], got -1");
  // The set-points wait for the scenario's keys (the mode), then are named with the rest.
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 0], [1, nan]]\n[controller.injection]\nF = 3\n"),
            path_of("inline.toml") + ":2: operation.speed_rad_s: point 1: value must be a number in [-2000, 2000] rad/s, got nan\n" +
                path_of("inline.toml") + ":4: controller.injection.F: unknown key (did you mean controller.injection.F_A?)");
}

// The [controller] table keeps its lines (it is not copied).
// [plant] and [controller] are read by their own parsers; given as anything but a section they
// are an error, not skipped with every key they were meant to hold.
TEST(Scenario, APlantOrControllerThatIsNoSectionIsAnError) {
  EXPECT_EQ(inline_error("plant = \"x\"\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":1: plant: expected a table (section [plant]), got a string");
  EXPECT_EQ(inline_error("controller = 5\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":1: controller: expected a table (section [controller]), got an integer");
}

// A profile is inline or from a CSV: both in one file is a mistake, named with both lines.
TEST(Scenario, AProfileBothInlineAndFromCsvIsAnError) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\nspeed_csv = \"speed.csv\"\n"),
            path_of("inline.toml") +
                ":3: operation.speed_csv: given together with operation.speed_rad_s (line 2): a profile is either inline "
                "or from a CSV file; remove one");
  // Across bases the nearest file's profile holds, in whichever form it gives it.
  const Scenario csv = load_scenario(kDir / "scenario_child_csv.toml");
  EXPECT_EQ(csv.scenario.speed_rad_s.points.size(), 3U) << "the child's CSV replaces the base's inline points";
  EXPECT_EQ(load_scenario(kDir / "scenario_grandchild_none.toml").scenario.speed_rad_s.points.size(), 3U);
  const Scenario back = load_scenario(kDir / "scenario_grandchild_inline.toml");
  ASSERT_EQ(back.scenario.speed_rad_s.points.size(), 1U) << "the grandchild's inline points replace the CSV";
  EXPECT_EQ(back.scenario.speed_rad_s.points[0].value, 7.0);
  // Too short to see a thermal update.
  EXPECT_EQ(inline_error("[scenario]\nduration_s = 1e-5\n[operation]\nspeed_rad_s = [[0, 1]]\n"),
            path_of("inline.toml") + ":2: scenario.duration_s: must be in [0.1, 1e+06], got 1e-05");
}

// A set-point profile of the other mode would be ignored: refused, naming its line. A file
// that sets the mode leaves its base's profile of the other mode behind.
TEST(Scenario, AProfileOfTheOtherModeIsAnError) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\ntorque_Nm = [[0, 5]]\n"),
            path_of("inline.toml") +
                ":3: operation.torque_Nm: a set-point of torque mode, but operation.mode is \"speed\" (the default); it "
                "would be ignored (the load's torque is [plant.load]): remove it or set the mode");
  // Told before the profile is read: the line, not a missing file or a value out of range.
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\ntorque_csv = \"no_such.csv\"\n")
                .rfind(path_of("inline.toml") + ":3: operation.torque_csv: a set-point of torque mode", 0),
            0U);
  EXPECT_EQ(inline_error("[operation]\nmode = \"torque\"\nspeed_rad_s = [[0, 1]]\n")
                .rfind(path_of("inline.toml") + ":3: operation.speed_rad_s: a set-point of speed mode", 0),
            0U);
  EXPECT_EQ(inline_error("[operation]\nmode = \"torque\"\ntorque_Nm = [[0, 5]]\nspeed_csv = \"speed_profile.csv\"\n"),
            path_of("inline.toml") +
                ":4: operation.speed_csv: a set-point of speed mode, but operation.mode is \"torque\"; it would be "
                "ignored (the speed follows the load, [plant.load]): remove it or set the mode");
  // A torque scenario on a speed base (which has speed_rad_s): the base's speeds stay behind.
  const Scenario t = parse("[scenario]\nbase = \"scenario_base.toml\"\n[operation]\nmode = \"torque\"\ntorque_Nm = [[0, 5]]\n");
  EXPECT_EQ(t.scenario.mode, core::DriveMode::kTorque);
  EXPECT_TRUE(t.scenario.speed_rad_s.empty());
  EXPECT_EQ(t.scenario.torque_Nm.at(1.0), 5.0);
  // Without the mode set in the file, the base's mode holds and the torque profile is refused.
  EXPECT_EQ(inline_error("[scenario]\nbase = \"scenario_base.toml\"\n[operation]\ntorque_Nm = [[0, 5]]\n")
                .rfind(path_of("inline.toml") + ":4: operation.torque_Nm: a set-point of torque mode", 0),
            0U);
}

// A file that chooses another load profile or EMF shape leaves its base's tables of the old
// one behind: no way to unset an inherited key, and the plant refuses a table its choice does
// not use (a fan load on a steps base was refused at the base's line).
TEST(Scenario, AnotherLoadProfileOrEmfShapeLeavesTheBasesTablesBehind) {
  const Scenario fan = parse("[scenario]\nbase = \"scenario_base_loaded.toml\"\n[plant.load]\nprofile = \"fan\"\n"
                             "fan_k_Nm_s2 = 1e-4\n[plant.emf]\nshape = \"trapezoidal\"\n");
  EXPECT_EQ(fan.plant.load.profile, plant::LoadProfile::fan);
  EXPECT_TRUE(fan.plant.load.points.empty());
  EXPECT_EQ(fan.plant.load.torque_Nm, 2.0);  // not a table of the old profile: kept
  EXPECT_EQ(fan.plant.emf.shape, plant::EmfShape::trapezoidal);
  // Without the choice, the base's tables hold.
  const Scenario same = parse("[scenario]\nbase = \"scenario_base_loaded.toml\"\n[plant.load]\ntorque_Nm = 3.0\n");
  EXPECT_EQ(same.plant.load.profile, plant::LoadProfile::torque_steps);
  EXPECT_EQ(same.plant.load.points.size(), 2U);
  EXPECT_EQ(same.plant.emf.shape, plant::EmfShape::custom);
  // The same profile chosen again with its own table: the file's table.
  const Scenario steps = parse("[scenario]\nbase = \"scenario_base_loaded.toml\"\n[plant.load]\nprofile = \"steps\"\n"
                               "steps = [[0.0, 1.0]]\n");
  ASSERT_EQ(steps.plant.load.points.size(), 1U);
}

TEST(Scenario, ControllerErrorNamesTheLine) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 1]]\n[controller.injection]\nF_A = 2000\n"),
            path_of("inline.toml") + ":4: controller.injection.F_A: must be in (0, 1000], got 2000");
}

// Keys that override a base keep their lines.
TEST(Scenario, ErrorInAnOverrideOfABaseNamesTheLine) {
  EXPECT_EQ(inline_error("[scenario]\nbase = \"scenario_base.toml\"\nduration_s = -1\n"),
            path_of("inline.toml") + ":3: scenario.duration_s: must be in [0.1, 1e+06], got -1");
}

// So do plant overrides in a scenario that has a base.
TEST(Scenario, PlantOverrideErrorInAChildNamesTheLine) {
  EXPECT_EQ(inline_error("[scenario]\nbase = \"scenario_base.toml\"\n[plant.motor]\nld_H = -1.0\n")
                .rfind(path_of("inline.toml") + ":4: plant.motor.ld_H: must be", 0),
            0U)
      << inline_error("[scenario]\nbase = \"scenario_base.toml\"\n[plant.motor]\nld_H = -1.0\n");
}

// The base's plant.profile and operation.speed_csv are relative to the base.
TEST(Scenario, BasePathsAreRelativeToTheBase) {
  const Scenario a = load_scenario(kDir / "sub/scenario_child_in_subdir.toml");
  EXPECT_EQ(a.scenario.name, "child in a subdirectory");
  EXPECT_EQ(a.plant.motor.ld_H, 6.0e-3);  // from the base's profile, next to the base
  const Scenario b = load_scenario(kDir / "sub/scenario_child_of_csv_base.toml");
  EXPECT_EQ(b.scenario.speed_rad_s.at(2.0), 150.0);  // the base's CSV, next to the base
}

TEST(Scenario, PlantOverridesMergeOntoTheProfile) {
  const Scenario s = parse(R"([operation]
speed_rad_s = [[0, 100]]
[plant]
profile = "plant_profile.toml"
[plant.motor]
rs_ohm = 0.2
[plant.inverter]
dead_time_s = 2e-6
)");
  EXPECT_EQ(s.plant.motor.rs_ohm, 0.2);                        // override
  EXPECT_EQ(s.plant.motor.ld_H, 6.0e-3);                       // profile, same table as the override
  EXPECT_EQ(s.plant.emf.shape, plant::EmfShape::sinusoidal);   // profile
  EXPECT_EQ(s.plant.inverter.dead_time_s, 2e-6);               // override
  EXPECT_EQ(s.plant.inverter.dc_bus_V, plant::PlantConfig{}.inverter.dc_bus_V);  // default
}

TEST(Scenario, PlantOverrideErrorPointsAtTheScenarioLine) {
  const std::string text = R"([operation]
speed_rad_s = [[0, 100]]
[plant]
profile = "plant_profile.toml"
[plant.motor]
ld_H = -1.0
)";
  const std::string e = inline_error(text);
  EXPECT_EQ(e.rfind(path_of("inline.toml") + ":6: plant.motor.ld_H: must be", 0), 0U) << e;
  const std::string unknown = inline_error(R"([operation]
speed_rad_s = [[0, 100]]
[plant.motor]
rs_ohmm = 0.2
)");
  EXPECT_EQ(unknown, path_of("inline.toml") + ":4: plant.motor.rs_ohmm: unknown key (did you mean plant.motor.rs_ohm?)");
}

// Every bad override is pointed at its own line (the plant lists them one a line; the second
// was left with a line number of the merged table and no plant. prefix).
TEST(Scenario, EachBadPlantOverrideNamesItsOwnLine) {
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 100]]\n[plant.inverter]\ndc_ripple_fraction = 0.9\ndead_time_s = 1.0\n"),
            path_of("inline.toml") + ":4: plant.inverter.dc_ripple_fraction: must be in [0, 0.5], got 0.9\n" +
                path_of("inline.toml") + ":5: plant.inverter.dead_time_s: must be in [0, 0.0001], got 1");
}

TEST(Scenario, ErrorInTheProfileNamesTheProfile) {
  const std::string e = inline_error("[operation]\nspeed_rad_s = [[0, 100]]\n[plant]\nprofile = \"bad_profile.toml\"\n");
  EXPECT_EQ(e.rfind(path_of("bad_profile.toml") + ":4: motor.ld_H: must be", 0), 0U) << e;
  EXPECT_EQ(inline_error("[operation]\nspeed_rad_s = [[0, 100]]\n[plant]\nprofile = 3\n"),
            path_of("inline.toml") + ": plant.profile: expected a path (string)");
}

TEST(Scenario, AmbientSeedAndAccelerationReachPlantAndController) {
  const Scenario s = parse(R"([scenario]
ambient_C = 35.0
thermal_acceleration = 50.0
seed = 42
[operation]
speed_rad_s = [[0, 100]]
)");
  EXPECT_EQ(s.plant.thermal.ambient_C, 35.0);
  EXPECT_EQ(s.plant.thermal.acceleration, 50.0);
  EXPECT_EQ(s.controller.drive.thermal.time_scale, 50.0);
  EXPECT_EQ(s.plant.simulation.seed, 42U);
  // Explicit plant and controller values win.
  const Scenario t = parse(R"([scenario]
ambient_C = 35.0
thermal_acceleration = 50.0
[operation]
speed_rad_s = [[0, 100]]
[plant.thermal]
ambient_C = 20.0
[controller.thermal]
acceleration = 10.0
gate_sigma = 4.0
)");
  EXPECT_EQ(t.plant.thermal.ambient_C, 20.0);
  EXPECT_EQ(t.plant.thermal.acceleration, 50.0);
  EXPECT_EQ(t.controller.drive.thermal.time_scale, 10.0);
  EXPECT_EQ(t.controller.drive.thermal.gate_sigma, 4.0);
  // A controller.thermal table without acceleration keeps its keys and gets the acceleration.
  const Scenario u = parse(R"([scenario]
thermal_acceleration = 50.0
[operation]
speed_rad_s = [[0, 100]]
[controller.thermal]
gate_sigma = 4.0
)");
  EXPECT_EQ(u.controller.drive.thermal.time_scale, 50.0);
  EXPECT_EQ(u.controller.drive.thermal.gate_sigma, 4.0);
  // The plant's own acceleration and seed win as its ambient does (they were overwritten by the
  // scenario's, silently).
  const Scenario w = parse(R"([scenario]
thermal_acceleration = 50.0
seed = 42
[operation]
speed_rad_s = [[0, 100]]
[plant.thermal]
acceleration = 3.0
[plant.simulation]
seed = 7
)");
  EXPECT_EQ(w.plant.thermal.acceleration, 3.0);
  EXPECT_EQ(w.plant.simulation.seed, 7U);
  EXPECT_EQ(w.controller.drive.thermal.time_scale, 50.0);
  // Below the plant's least acceleration: named in the scenario, before anything runs.
  EXPECT_EQ(inline_error("[scenario]\nthermal_acceleration = 0.0005\n[operation]\nspeed_rad_s = [[0, 100]]\n"),
            path_of("inline.toml") + ":2: scenario.thermal_acceleration: must be in [0.001, 100000], got 0.0005");
  // An ambient profile sets the plant's starting ambient.
  const Scenario v = parse(R"([scenario]
ambient_profile = [0, 18, 100, 40]
[operation]
speed_rad_s = [[0, 100]]
)");
  EXPECT_EQ(v.plant.thermal.ambient_C, 18.0);
  EXPECT_EQ(v.scenario.ambient_profile.at(50.0), 29.0);
}

TEST(Scenario, CsvSetPoints) {
  const Scenario s = parse("[operation]\nspeed_csv = \"speed_profile.csv\"\n");
  ASSERT_EQ(s.scenario.speed_rad_s.points.size(), 3U);
  EXPECT_EQ(s.scenario.speed_rad_s.points[1].time_s, 0.5);
  EXPECT_EQ(s.scenario.speed_rad_s.points[1].value, 50.0);
  EXPECT_EQ(s.scenario.speed_rad_s.at(1.25), 100.0);
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"speed_bad_times.csv\"\n"),
            path_of("speed_bad_times.csv") + ":4: operation.speed_csv: times must ascend (1 after 2)");
  // A row is two numbers and nothing else: an extra column is refused, not ignored.
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"speed_extra_column.csv\"\n"),
            path_of("speed_extra_column.csv") + ":3: operation.speed_csv: expected 2 columns 'time_s,value', got 3: '1.0,50,7'");
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"speed_nan.csv\"\n"),
            path_of("speed_nan.csv") + ":3: operation.speed_csv: value must be a number in [-2000, 2000] rad/s, got nan");
  // Decimal numbers only: strtod read 0x10 as 16.
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"speed_hex.csv\"\n"),
            path_of("speed_hex.csv") + ":3: operation.speed_csv: expected 'time_s,value' (two numbers), got '1.0,0x10'");
  // A first line with a digit is a row, not a header: malformed, it is named (",100" was dropped).
  EXPECT_EQ(inline_error("[operation]\nspeed_csv = \"speed_first_row_malformed.csv\"\n"),
            path_of("speed_first_row_malformed.csv") +
                ":1: operation.speed_csv: expected 'time_s,value' (two numbers), got ',100'");
  // A long line is cut in the message, its length said.
  const pmsm::test::ScratchDir scratch{"pmsm-csv"};
  const std::filesystem::path long_csv = scratch / "long-row.csv";
  std::ofstream(long_csv) << "time_s,speed_rad_s\n0," << std::string(1000000, '7') << "x\n";
  const std::string long_error = inline_error("[operation]\nspeed_csv = \"" + long_csv.string() + "\"\n");
  EXPECT_LT(long_error.size(), 400U);
  EXPECT_NE(long_error.find("got '0," + std::string(78, '7') + "... (1000003 bytes)'"), std::string::npos) << long_error;
  // A spreadsheet's byte-order mark before the header, and blank lines of spaces, are no rows
  // ("got '\xEF\xBB\xBF0,0'" and "got '  '" were).
  const std::filesystem::path bom_csv = scratch / "bom.csv";
  std::ofstream(bom_csv) << "\xEF\xBB\xBFtime_s,speed_rad_s\r\n0,0\r\n   \r\n2,40\r\n";
  const Scenario bom = parse("[operation]\nspeed_csv = \"" + bom_csv.string() + "\"\n");
  std::ofstream(bom_csv) << "\xEF\xBB\xBF" << "0,0\n1,10\n";
  const Scenario bom_no_header = parse("[operation]\nspeed_csv = \"" + bom_csv.string() + "\"\n");
  EXPECT_EQ(bom.scenario.speed_rad_s.at(1.0), 20.0);
  EXPECT_EQ(bom_no_header.scenario.speed_rad_s.at(1.0), 10.0);
  const Scenario t = parse("[operation]\nmode = \"torque\"\ntorque_csv = \"speed_profile.csv\"\n");
  EXPECT_EQ(t.scenario.mode, core::DriveMode::kTorque);
  EXPECT_EQ(t.scenario.torque_Nm.at(2.0), 150.0);
}

TEST(Profile, InterpolatesAndClamps) {
  Profile p;
  EXPECT_EQ(p.at(1.0), 0.0);
  EXPECT_TRUE(p.empty());
  p.points = {{1.0, 10.0}, {3.0, 30.0}, {4.0, -10.0}};
  EXPECT_EQ(p.at(-5.0), 10.0);   // held before the first point
  EXPECT_EQ(p.at(1.0), 10.0);
  EXPECT_EQ(p.at(2.0), 20.0);
  EXPECT_EQ(p.at(3.0), 30.0);
  EXPECT_EQ(p.at(3.25), 20.0);
  EXPECT_EQ(p.at(4.0), -10.0);
  EXPECT_EQ(p.at(100.0), -10.0);  // held after the last
  Profile one;
  one.points = {{2.0, 7.0}};
  EXPECT_EQ(one.at(0.0), 7.0);
  EXPECT_EQ(one.at(9.0), 7.0);
}

TEST(Scenario, KeysMarkdownListsTheScenarioKeys) {
  const std::string md = scenario_keys_markdown();
  for (const char* key : {"scenario.duration_s", "scenario.ambient_profile", "operation.mode", "metrics.log_period_s"}) {
    EXPECT_NE(md.find(std::string("`") + key + "`"), std::string::npos) << key;
  }
}

}  // namespace
}  // namespace pmsm::app
