// The planning command as a commissioning engineer runs it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <unistd.h>

#include "run_process.hpp"
#include "scratch_dir.hpp"

namespace pmsm::test {
namespace {

const std::string kExe = PMSM_THERMAL_EXE;

TEST(PlanCli, AFirstWordThatIsNoCommandIsNamedWithTheCommands) {
  const ProcessResult r = run_process(kExe + " bogus");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("pmsm-thermal: 'bogus' is not a command; the commands are budget, losses, simulate"), std::string::npos)
      << r.err;
}

// CLI11 checks what is required before the words it does not know: an unknown flag came out as
// "A subcommand is required" or "... is required", never named.
TEST(PlanCli, AnUnknownFlagIsNamedBeforeWhatIsMissing) {
  for (const char* args : {" --bogus", " budget --bogus", " simulate --bogus", " budget --speed 100 --bogus"}) {
    const ProcessResult r = run_process(kExe + args);
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_NE(r.err.find("The following argument was not expected: --bogus"), std::string::npos) << args << ": " << r.err;
    const std::size_t first = r.err.find("not expected");
    EXPECT_EQ(r.err.find("not expected", first + 1), std::string::npos) << "named once: " << r.err;
  }
}

TEST(PlanCli, BudgetGivenVoltageMatchesEq29) {
  const ProcessResult r =
      run_process(kExe + " budget --Ld 0.009 --Rs 0.133 --Tw 0.01 --window blackman --voltage 40 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double expected = 40.0 / std::sqrt(std::pow(1.81 * 0.009 / 0.01, 2) + 0.133 * 0.133);
  EXPECT_NEAR(json_number(r.out, "max_injection_current_A").value_or(-1) / expected, 1.0, 0.003);
  EXPECT_NEAR(json_number(r.out, "max_slope_per_Tw").value_or(-1), 1.81, 0.005);
  EXPECT_NEAR(json_number(r.out, "window_integral_per_Tw").value_or(-1), 0.84, 0.005);
}

TEST(PlanCli, BudgetGivenCurrentWithModifiedWindow) {
  const ProcessResult r =
      run_process(kExe + " budget --Ld 0.009 --Rs 0.133 --Tw 0.02 --window modified --current 50 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double expected = 50.0 * std::sqrt(std::pow(2.04 * 0.009 / 0.02, 2) + 0.133 * 0.133);
  EXPECT_NEAR(json_number(r.out, "required_voltage_V").value_or(-1) / expected, 1.0, 0.003);
  EXPECT_NEAR(json_number(r.out, "max_slope_per_Tw").value_or(-1), 2.04, 0.005);
  EXPECT_NEAR(json_number(r.out, "window_integral_per_Tw").value_or(-1), 1.25, 0.005);
}

TEST(PlanCli, BudgetAtSpeedLeavesLessForPositiveInjection) {
  const ProcessResult r = run_process(kExe + " budget --Ld 0.0055 --speed 200 --iq 30 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double pos = json_number(r.out, "max_positive_injection_current_A").value_or(-1);
  const double neg = json_number(r.out, "max_negative_injection_current_A").value_or(-1);
  EXPECT_GT(pos, 0.0);
  EXPECT_LT(pos, neg);
  EXPECT_DOUBLE_EQ(json_number(r.out, "max_injection_current_A").value_or(-1), pos);
}

// On a salient machine the drive's torque budget (injection.max_torque_disturbance_Nm) limits F
// to budget / (1.5 p |Ld - Lq| |iq|) before the voltage does: the 30 mohm IPM at 200 rad/s and
// 50 A, 1.5 Nm: 1.5 / (1.5 x 4 x 0.2 mH x 50 A) = 25 A. Without a budget, or on a round rotor,
// the voltage decides as before.
TEST(PlanCli, BudgetAtSpeedKeepsTheTorqueBudget) {
  const std::string ipm = kExe + " budget --speed 200 --iq 50 --Ld 0.25e-3 --Lq 0.45e-3 --pole-pairs 4 --Ke 0.5 "
                                 "--vdc 320 --Rs 0.03 --json";
  const ProcessResult with = run_process(ipm + " --max-torque-disturbance 1.5");
  ASSERT_EQ(with.exit_code, 0) << with.err;
  EXPECT_NEAR(json_number(with.out, "max_torque_injection_current_A").value_or(-1), 25.0, 1e-9);
  EXPECT_NEAR(json_number(with.out, "max_injection_current_A").value_or(-1), 25.0, 1e-9);
  const ProcessResult without = run_process(ipm);
  ASSERT_EQ(without.exit_code, 0) << without.err;
  EXPECT_FALSE(json_number(without.out, "max_torque_injection_current_A").has_value()) << without.out;
  EXPECT_GT(json_number(without.out, "max_injection_current_A").value_or(-1), 100.0) << "the voltage alone";
  const ProcessResult round = run_process(kExe + " budget --speed 200 --iq 50 --max-torque-disturbance 1.5 --json");
  ASSERT_EQ(round.exit_code, 0) << round.err;
  EXPECT_FALSE(json_number(round.out, "max_torque_injection_current_A").has_value()) << "Ld = Lq: no reluctance torque";
}

// The current limit motoring and injection share, as the scheduler applies it to
// fixed-magnitude pulses: |(+-F, iq)| within it, sqrt(65^2 - 25^2) = 60 A at 25 A of iq; nothing
// left where iq alone reaches it; no limit, no line.
TEST(PlanCli, BudgetAtSpeedKeepsTheCurrentLimit) {
  const std::string base = kExe + " budget --speed 10 --json";
  const ProcessResult limited = run_process(base + " --iq 25 --current-limit 65");
  ASSERT_EQ(limited.exit_code, 0) << limited.err;
  EXPECT_NEAR(json_number(limited.out, "max_current_injection_current_A").value_or(-1), 60.0, 1e-9);
  EXPECT_NEAR(json_number(limited.out, "max_injection_current_A").value_or(-1), 60.0, 1e-9) << "the voltage allows more";
  const ProcessResult full = run_process(base + " --iq 70 --current-limit 65");
  ASSERT_EQ(full.exit_code, 0) << full.err;
  EXPECT_EQ(json_number(full.out, "max_injection_current_A").value_or(-1), 0.0);
  EXPECT_NE(full.out.find("\"iq_beyond_current_limit\": true"), std::string::npos) << full.out;
  EXPECT_NE(limited.out.find("\"iq_beyond_current_limit\": false"), std::string::npos) << limited.out;
  EXPECT_NE(run_process(kExe + " budget --speed 10 --iq 70 --current-limit 65").out.find("at or beyond the current limit"),
            std::string::npos);
  const ProcessResult none = run_process(base + " --iq 25");
  ASSERT_EQ(none.exit_code, 0) << none.err;
  EXPECT_FALSE(json_number(none.out, "max_current_injection_current_A").has_value()) << none.out;
  EXPECT_GT(json_number(none.out, "max_injection_current_A").value_or(-1), 60.0) << "the voltage alone";
  const ProcessResult text = run_process(kExe + " budget --speed 10 --iq 25 --current-limit 65");
  EXPECT_NE(text.out.find("largest F for current  60.00 A"), std::string::npos) << text.out;
  EXPECT_NE(run_process(base + " --current-limit -1").exit_code, 0);
}

// A speed whose EMF alone passes the voltage limit (Eq. 3 at id = 0: 1.19 V s/rad line RMS
// at 10,000 rad/s) is said to need field weakening, not answered with a bare F = 0.
TEST(PlanCli, BudgetBeyondTheVoltageLimitSaysSo) {
  const ProcessResult beyond = run_process(kExe + " budget --speed 10000 --json");
  ASSERT_EQ(beyond.exit_code, 0) << beyond.err;
  EXPECT_NE(beyond.out.find("\"motoring_beyond_voltage_limit\": true"), std::string::npos) << beyond.out;
  EXPECT_EQ(json_number(beyond.out, "max_injection_current_A").value_or(-1), 0.0);
  EXPECT_NE(run_process(kExe + " budget --speed 10000").out.find("only in field weakening"), std::string::npos);
  const ProcessResult within = run_process(kExe + " budget --speed 200");
  EXPECT_EQ(within.out.find("field weakening"), std::string::npos) << within.out;
  EXPECT_NE(run_process(kExe + " budget --speed 200 --json").out.find("\"motoring_beyond_voltage_limit\": false"),
            std::string::npos);
}

// A drive's own configuration (pmsm-thermald's [controller] section) gives every option the
// command line does not: the motor, the bus, the voltage fraction, the window and its Tw, the
// torque budget, the margin (the file's, else the drive's default at the bus planned with),
// and Lq as the commissioned secant at --iq (here the flux map's Hermite curve between its 70
// and 106 A points: 0.41987 mH at 75 A). A flag still wins; a bad or missing file, or one with
// no drive in it, is named and refused.
TEST(PlanCli, BudgetTakesADrivesConfiguration) {
  const ScratchDir dir{"pmsm-plan"};
  const std::filesystem::path axis = dir.path() / "axis.toml";
  std::ofstream(axis) << "[can]\ninterface = \"vcan0\"\n"
                         "[controller.motor]\nrs_ohm = 0.0315\nld_H = 0.275e-3\nlq_H = 0.4275e-3\n"
                         "lq_map_current_A = [35.0, 70.0, 106.0, 141.0]\n"
                         "lq_map_H = [0.42573e-3, 0.42079e-3, 0.41338e-3, 0.40497e-3]\n"
                         "ke_V_s_per_rad = 0.4925\npole_pairs = 4\ncontinuous_current_A_rms = 100.0\n"
                         "[controller.sensors]\ncurrent_range_A = 400.0\n"
                         "[controller.control]\nnominal_dc_bus_V = 320.0\nvoltage_limit_fraction = 0.9\n"
                         "[controller.derating]\nmax_current_A = 300.0\n"
                         "[controller.injection]\nmax_torque_disturbance_Nm = 1.5\nwindow = \"blackman\"\nTw_s = 0.006\n";
  const std::string base = kExe + " budget --config " + axis.string() + " --speed 314 --iq 75 --json";
  const ProcessResult r = run_process(base);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(json_number(r.out, "ld_H").value_or(-1), 0.275e-3);
  EXPECT_EQ(json_number(r.out, "rs_ohm").value_or(-1), 0.0315);
  EXPECT_EQ(json_number(r.out, "Tw_s").value_or(-1), 0.006);
  EXPECT_NE(r.out.find("\"window\": \"blackman\""), std::string::npos) << r.out;
  EXPECT_EQ(json_number(r.out, "pole_pairs").value_or(-1), 4.0);
  EXPECT_EQ(json_number(r.out, "vdc_V").value_or(-1), 320.0);
  const double margin = 15.0 * 320.0 / 650.0;  // the drive's default at its bus
  EXPECT_NEAR(json_number(r.out, "margin_V").value_or(-1), margin, 1e-6);
  EXPECT_NEAR(json_number(r.out, "voltage_limit_V").value_or(-1), 0.9 * 320.0 / std::sqrt(3.0) - margin, 1e-6);
  const double lq = json_number(r.out, "lq_H").value_or(-1);
  EXPECT_NEAR(lq, 0.41987313e-3, 1e-10) << "the map's secant at 75 A";
  EXPECT_NEAR(json_number(r.out, "max_torque_injection_current_A").value_or(-1),
              1.5 / (1.5 * 4.0 * (lq - 0.275e-3) * 75.0), 1e-6);
  EXPECT_EQ(json_number(r.out, "current_limit_A").value_or(-1), 300.0) << "derating.max_current_A";
  EXPECT_NEAR(json_number(r.out, "max_current_injection_current_A").value_or(-1), std::sqrt(300.0 * 300.0 - 75.0 * 75.0),
              1e-6);
  // Ke: the motoring voltage at 314 rad/s is mostly the EMF, Ke sqrt(2/3) x 314 = 126 V.
  EXPECT_NEAR(json_number(r.out, "motoring_voltage_V").value_or(-1), 134.57, 0.1);
  // Flags win; the margin follows --vdc unless the file gives one.
  const ProcessResult flag = run_process(base + " --vdc 400 --Ld 0.3e-3 --Lq 0.4e-3 --current-limit 100");
  ASSERT_EQ(flag.exit_code, 0) << flag.err;
  EXPECT_EQ(json_number(flag.out, "current_limit_A").value_or(-1), 100.0);
  EXPECT_EQ(json_number(flag.out, "vdc_V").value_or(-1), 400.0);
  EXPECT_EQ(json_number(flag.out, "ld_H").value_or(-1), 0.3e-3);
  EXPECT_EQ(json_number(flag.out, "lq_H").value_or(-1), 0.4e-3);
  EXPECT_NEAR(json_number(flag.out, "margin_V").value_or(-1), 15.0 * 400.0 / 650.0, 1e-6);
  std::ofstream(axis, std::ios::app) << "headroom_margin_V = 5.0\n";
  const ProcessResult given = run_process(base + " --vdc 400");
  ASSERT_EQ(given.exit_code, 0) << given.err;
  EXPECT_EQ(json_number(given.out, "margin_V").value_or(-1), 5.0) << "the file's own margin";
  // A drive injecting a turning vector (fixed-angle, DC) keeps F within limit - |i|, as its
  // scheduler does: 300 - 75 A.
  std::ofstream(axis, std::ios::app) << "method = \"fixed-angle\"\n";
  const ProcessResult turning = run_process(base);
  ASSERT_EQ(turning.exit_code, 0) << turning.err;
  EXPECT_NEAR(json_number(turning.out, "max_current_injection_current_A").value_or(-1), 225.0, 1e-9);
  // A motor cable is in what the pulse's voltage drives through: its resistance at the
  // nameplate's temperature (25 C) joins the winding's, as in the drive's own budget.
  const std::filesystem::path cabled = dir.path() / "cabled.toml";
  std::ofstream(cabled) << "[can]\ninterface = \"vcan0\"\n"
                           "[controller.motor]\nrs_ohm = 0.0315\ncable_resistance_ohm = 0.01\n";
  const ProcessResult cable = run_process(kExe + " budget --config " + cabled.string() + " --speed 314 --iq 75 --json");
  ASSERT_EQ(cable.exit_code, 0) << cable.err;
  EXPECT_NEAR(json_number(cable.out, "rs_ohm").value_or(-1), 0.0315 + 0.01 * (234.5 + 25.0) / (234.5 + 20.0), 1e-9)
      << "(printed to ten digits)";
  // Refused: a bad key (named with its line), a file with no drive in it, a missing file.
  std::ofstream(dir.path() / "bad.toml") << "[controller.motor]\nld_H = -1\n";
  const ProcessResult bad = run_process(kExe + " budget --config " + (dir.path() / "bad.toml").string() + " --speed 3");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("bad.toml:2: controller.motor.ld_H: must be in [1e-09, 1], got -1"), std::string::npos) << bad.err;
  std::ofstream(dir.path() / "typo.toml") << "[controler.motor]\nld_H = 1e-3\n";
  const ProcessResult typo = run_process(kExe + " budget --config " + (dir.path() / "typo.toml").string() + " --speed 3");
  EXPECT_EQ(typo.exit_code, 2);
  EXPECT_NE(typo.err.find("typo.toml: no [controller] section"), std::string::npos) << typo.err;
  const ProcessResult missing = run_process(kExe + " budget --config " + (dir.path() / "none.toml").string() + " --speed 3");
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.err.find("--config"), std::string::npos) << missing.err;
}

// A margin that takes the whole voltage limit: named, not a budget of 0 A.
TEST(PlanCli, BudgetRefusesAMarginBeyondTheLimit) {
  const ProcessResult r = run_process(kExe + " budget --speed 100 --vdc 10 --margin 6");  // limit 5.48 V
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("takes the whole voltage limit"), std::string::npos) << r.err;
}

TEST(PlanCli, LossesFixedMagnitudeMatchesEq32) {
  const ProcessResult r = run_process(
      kExe + " losses --method fixed-magnitude --F 25 --Rs 0.133 --pulses 3 --elapsed 10 --Ti 0.2 --Tw 0.01 --window blackman --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NEAR(json_number(r.out, "average_loss_W").value_or(-1), 625.0 * 3 * 0.133 / 10.0 * (0.2 + 0.84 * 0.01), 0.005);
}

TEST(PlanCli, LossesFixedAngleMatchesEq31) {
  const ProcessResult r = run_process(
      kExe + " losses --method fixed-angle --F 50 --Rs 0.133 --pulses 3 --elapsed 10 --Ti 0.003 --Tw 0.001 --omega 500 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double bracket = 2.0 / 500.0 * std::sin(500.0 * 0.003 / 2.0) + 0.84 * 0.001;
  EXPECT_NEAR(json_number(r.out, "average_loss_W").value_or(-1), 2500.0 * 3 * 0.133 / 10.0 * bracket, 1e-4);
  EXPECT_TRUE(r.err.empty()) << r.err;  // a 86 degree arc: no warning
}

// Without options the plan is the drive's: its default motor (5.5 mH), window (modified) and
// edge (4 ms), not the paper's Fig. 8; and the loss's share is of the power asked for.
TEST(PlanCli, DefaultsAreTheDrivesOwn) {
  const ProcessResult r = run_process(kExe + " budget --current 10 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("\"window\": \"modified\""), std::string::npos) << r.out;
  EXPECT_EQ(json_number(r.out, "Tw_s").value_or(-1), 0.004);
  EXPECT_EQ(json_number(r.out, "ld_H").value_or(-1), 0.0055);
  const ProcessResult l = run_process(kExe + " losses --F 5 --rated-power 1500 --json");
  ASSERT_EQ(l.exit_code, 0) << l.err;
  EXPECT_NEAR(json_number(l.out, "fraction_of_rated_power").value_or(-1),
              json_number(l.out, "average_loss_W").value_or(0) / 1500.0, 1e-9);
}

TEST(PlanCli, HumanReadableByDefault) {
  const ProcessResult r = run_process(kExe + " budget --voltage 40");
  ASSERT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("largest injection F"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find('{'), std::string::npos);
}

// simulate loads every scenario before it runs any: one it cannot use stops them all, each
// such named with its file, line and key (docs/scenarios.md), and a calibration asked for at
// or after the run's end is one it cannot use.
TEST(SimulateCli, AnUnusableScenarioStopsTheRunBeforeAnythingRuns) {
  const ScratchDir scratch{"pmsm-sim-cli"};
  const std::filesystem::path& dir = scratch.path();
  const std::string base = std::string("[scenario]\nbase = \"") + PMSM_SOURCE_DIR + "/bench/scenarios/reference-fm-bipolar.toml\"\n";
  std::ofstream(dir / "ok.toml") << base << "duration_s = 0.6\n";
  std::ofstream(dir / "late.toml") << base << "duration_s = 1\n[operation]\ncalibrate_at_s = 100\n";
  const ProcessResult r = run_process(kExe + " simulate --json --quiet " + (dir / "ok.toml").string() + " " +
                                      (dir / "late.toml").string() + " " + (dir / "absent.toml").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.out, "") << "ok.toml ran before the others were found unusable";
  EXPECT_NE(r.err.find("late.toml:5: operation.calibrate_at_s: the calibration starts at operation.calibrate_at_s = 100 s, "
                       "not before the run ends at scenario.duration_s = 1 s"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("absent.toml: scenario: no such file"), std::string::npos) << r.err;
  const ProcessResult ok = run_process(kExe + " simulate --json --quiet " + (dir / "ok.toml").string());
  EXPECT_EQ(ok.exit_code, 0) << ok.err;
  EXPECT_NE(ok.out.find("\"sim_time_s\": 0.6"), std::string::npos) << "ok.toml alone runs: " << ok.out;
}

// An output is not written over anything the scenario reads or keeps (itself, a base, a CSV,
// the stored calibration), nor over the other output; an empty output name is refused. (Before,
// only the top-level scenario was guarded: --csv over the speed CSV or a base replaced it and
// exited 0, and --csv '' wrote nothing and said nothing.)
TEST(SimulateCli, AnOutputIsNotWrittenOverAnInput) {
  const ScratchDir scratch{"pmsm-sim-out"};
  const std::filesystem::path& dir = scratch.path();
  std::ofstream(dir / "base.toml") << "[scenario]\nbase = \"" << PMSM_SOURCE_DIR
                                   << "/bench/scenarios/reference-fm-bipolar.toml\"\nduration_s = 0.6\n";
  std::ofstream(dir / "speed.csv") << "time_s,speed_rad_s\n0,0\n1,10\n";
  std::ofstream(dir / "s.toml") << "[scenario]\nbase = \"base.toml\"\n[operation]\nspeed_csv = \"speed.csv\"\n"
                                   "[controller.calibration]\nfile = \"cal.toml\"\n";
  const std::string run = kExe + " simulate --quiet ";
  const std::string s = (dir / "s.toml").string();
  const auto refused = [&](const std::string& args, const std::string& message) {
    const ProcessResult r = run_process(run + args + " " + s);
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
  };
  refused("--csv " + (dir / "speed.csv").string(),
          "would write over " + (dir / "speed.csv").string() + ", which the scenario " + s + " reads");
  refused("--plot " + (dir / "." / "base.toml").string(), "would write over " + (dir / "base.toml").string());
  refused("--csv " + (dir / "cal.toml").string(), "would write over " + (dir / "cal.toml").string());
  refused("--csv " + s, "would write over the scenario " + s);
  refused("--csv " + (dir / "x").string() + " --plot " + (dir / "x").string(), "--csv and --plot name the same file");
  refused("--csv ''", "--csv: expected a file name, got an empty one");
  // Relative names of files that do not exist yet, as a user in the scenario's directory types
  // them: a name and the same name spelled with "./" or resolved by the scenario.
  const auto refused_here = [&](const std::string& args, const std::string& message) {
    const ProcessResult r = run_process("cd " + dir.string() + " && " + run + args + " s.toml");
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
  };
  refused_here("--csv cal.toml", "would write over " + (dir / "cal.toml").string());
  refused_here("--csv ./y.csv --plot y.csv", "--csv and --plot name the same file");
  EXPECT_FALSE(std::filesystem::exists(dir / "cal.toml"));
  std::stringstream kept;
  kept << std::ifstream(dir / "speed.csv").rdbuf();
  EXPECT_EQ(kept.str(), "time_s,speed_rad_s\n0,0\n1,10\n");
}

// A scenario's name and the output's path reach gnuplot's script as strings: a name that closed
// its quote and went on a new line ran `system` (a file was created); a quote in either made
// gnuplot fail. Now they are quoted, and a name with a line break is refused at load (a
// control character in any string key is).
TEST(SimulateCli, TheScenariosNameIsTextInThePlotNotCommands) {
  const ScratchDir scratch{"pmsm-sim-plot"};
  const std::filesystem::path& dir = scratch.path();
  const std::filesystem::path pwned = dir / "pwned";
  std::ofstream(dir / "s.toml") << "[scenario]\nbase = \"" << PMSM_SOURCE_DIR
                                << "/bench/scenarios/reference-fm-bipolar.toml\"\nduration_s = 0.6\n"
                                << "name = \"it's \\\"x\\\"\\nsystem \\\"touch " << pwned.string()
                                << "\\\"\\nset title \\\"y\"\n";
  const std::filesystem::path png = dir / "it's.png";
  const ProcessResult refused = run_process(kExe + " simulate --quiet --plot \"" + png.string() + "\" " + (dir / "s.toml").string());
  EXPECT_EQ(refused.exit_code, 2) << refused.err;
  EXPECT_NE(refused.err.find("s.toml:4: scenario.name: contains a control character (U+000A) at position 9"), std::string::npos)
      << refused.err;
  EXPECT_FALSE(std::filesystem::exists(pwned)) << "the scenario's name ran a command";
  // Quotes of both kinds in the name and in the path: one line, quoted in the script.
  std::ofstream(dir / "q.toml") << "[scenario]\nbase = \"" << PMSM_SOURCE_DIR
                                << "/bench/scenarios/reference-fm-bipolar.toml\"\nduration_s = 0.6\n"
                                << "name = \"it's \\\"x\\\" system \\\"touch " << pwned.string() << "\\\"\"\n";
  const ProcessResult r = run_process(kExe + " simulate --quiet --plot \"" + png.string() + "\" " + (dir / "q.toml").string());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(std::filesystem::exists(png)) << r.err;
  EXPECT_FALSE(std::filesystem::exists(pwned)) << "the scenario's name ran a command";
  // In a Markdown row a '|' of the name is escaped: it would end the cell and shift the figures.
  // (1.2 s: past the calibration's rotor-angle check, which ends measured at 0.9 s.)
  std::ofstream(dir / "bar.toml") << "[scenario]\nbase = \"" << PMSM_SOURCE_DIR
                                  << "/bench/scenarios/reference-fm-bipolar.toml\"\nduration_s = 1.2\nname = \"a | b\"\n";
  const ProcessResult md = run_process(kExe + " simulate --quiet --markdown " + (dir / "bar.toml").string());
  EXPECT_EQ(md.exit_code, 0) << md.err;
  EXPECT_NE(md.out.find("| a \\| b (`bar.toml`) | fixed-magnitude bipolar |"), std::string::npos) << md.out;
  // A calibration check that ran and did not measure is said in the row: a rotor at rest is not
  // turning, so its encoder's angle was not checked (the JSON says it; the row did not).
  std::ofstream(dir / "rest.toml") << "[scenario]\nbase = \"" << PMSM_SOURCE_DIR
                                   << "/bench/scenarios/standstill-fm-bipolar.toml\"\nduration_s = 0.6\n";
  const ProcessResult rest = run_process(kExe + " simulate --quiet --markdown " + (dir / "rest.toml").string());
  EXPECT_EQ(rest.exit_code, 0) << rest.err;
  EXPECT_NE(rest.out.find("(`rest.toml`) — angle check: not_turning |"), std::string::npos) << rest.out;
  EXPECT_EQ(md.out.find("angle check"), std::string::npos) << "the reference's check measured: " << md.out;
  // An output that cannot take the series fails with exit 3 and says so.
  const ProcessResult full = run_process(kExe + " simulate --quiet --csv /dev/full " + (dir / "q.toml").string());
  EXPECT_EQ(full.exit_code, 3);
  EXPECT_NE(full.err.find("cannot write /dev/full"), std::string::npos) << full.err;
  // One that cannot be written at all is said before the run (it ran the whole scenario first,
  // then said only "cannot write adir"): no output on standard output, no figures.
  std::filesystem::create_directories(dir / "adir");
  for (const std::string& args : {" --csv " + (dir / "adir").string(), " --plot " + (dir / "adir").string(),
                                  " --csv " + (dir / "missing" / "x.csv").string()}) {
    const ProcessResult early = run_process(kExe + " simulate" + args + " " + (dir / "q.toml").string());
    EXPECT_EQ(early.exit_code, 3) << args;
    EXPECT_NE(early.err.find(": cannot write it ("), std::string::npos) << early.err;
    EXPECT_NE(early.err.find("nothing was run"), std::string::npos) << early.err;
    EXPECT_EQ(early.out, "") << "not run";
  }
}

struct BadInput {
  std::string args;
  std::string expected_in_message;
};

class PlanCliBadInput : public ::testing::TestWithParam<BadInput> {};

TEST_P(PlanCliBadInput, NamesTheFlagAndFails) {
  const ProcessResult r = run_process(kExe + " " + GetParam().args);
  EXPECT_EQ(r.exit_code, 2) << r.err;  // unusable input, as a bad file is (not CLI11's own codes)
  EXPECT_NE(r.err.find(GetParam().expected_in_message), std::string::npos) << r.err;
}

INSTANTIATE_TEST_SUITE_P(
    Flags, PlanCliBadInput,
    ::testing::Values(BadInput{"budget --Ld -1 --voltage 3", "--Ld"},
                      // decimal numbers only, as the files read them (0x10 was 16 V); whole numbers
                      // said so (--pulses 1e6 was "Could not convert", --node x "Value x not in range")
                      BadInput{"budget --voltage 0x10", "--voltage: expected a number, got '0x10'"},
                      BadInput{"losses --F 1 --pulses 1e6", "--pulses: expected a whole number, got '1e6'"},
                      BadInput{"dbc --node x", "--node: expected a whole number, got 'x'"},
                      BadInput{"budget --voltage 1e5 --Ld 1e-200 --Rs 1e-6", "--Ld"},  // printed "inf A"
                      // command: a setting that would not be sent is refused, not ignored; a period the
                      // daemon's command timeout (0.5 s as shipped) would trip between frames is refused
                      BadInput{"command --node 1 --speed 100 --duration 0.2 --injection-interval 5", "give --inject-now too"},
                      BadInput{"command --node 1 --speed 100 --period-ms 1000", "--period-ms: must be <= 250"},
                      BadInput{"budget --voltage 1e5 --Ld 0.009 --Rs 1e-200", "--Rs"},
                      BadInput{"budget --Ld 0.009", "--voltage,--current,--speed"},
                      BadInput{"budget --voltage 3 --current 2", "--voltage,--current,--speed"},
                      BadInput{"budget --window hamming --voltage 3", "--window"},
                      BadInput{"budget --Tw 0 --voltage 3", "--Tw"},
                      BadInput{"losses --F abc", "--F"},
                      BadInput{"losses --Rs 0.1", "--F"},
                      BadInput{"losses --F 25 --pulses 0", "--pulses"},
                      BadInput{"losses --F 25 --method fixed-angle", "--omega"},
                      BadInput{"losses --F 25 --method trapezoid", "--method"},
                      // An option the computation asked for does not use: refused, not ignored.
                      BadInput{"budget --voltage 5 --iq 50", "--iq requires --speed"},
                      BadInput{"budget --current 5 --Lq 1e-3", "--Lq requires --speed"},
                      BadInput{"budget --voltage 5 --pole-pairs 4", "--pole-pairs requires --speed"},
                      BadInput{"budget --voltage 5 --max-torque-disturbance 1", "--max-torque-disturbance requires --speed"},
                      BadInput{"budget --speed 100 --max-torque-disturbance -1", "--max-torque-disturbance"},
                      BadInput{"losses --F 25 --omega 300", "--omega applies to --method fixed-angle only"},
                      BadInput{"", "subcommand"},
                      // Not a finite number, or beyond any machine: refused, never printed as nan or inf.
                      BadInput{"budget --speed 100 --iq nan", "--iq: expected a number, got 'nan'"},
                      BadInput{"budget --speed 1e308", "--speed: must be <= 10000"},
                      BadInput{"budget --speed inf", "--speed: expected a number"},
                      BadInput{"budget --voltage 1e400", "--voltage: expected a number"},
                      BadInput{"losses --F nan", "--F: expected a number"},
                      // Finite but so small that a result overflows (inf V, a share of 8e299 %).
                      BadInput{"budget --current 10 --Tw 1e-300", "--Tw: must be >= 1e-06"},
                      BadInput{"losses --F 10 --rated-power 1e-300", "--rated-power: must be >= 1"},
                      // 1000 pulses of 30 ms in 1 s: a duty above 100 %.
                      BadInput{"losses --F 10 --pulses 1000 --elapsed 1 --Ti 0.01", "more than --elapsed 1 s"}));

}  // namespace
}  // namespace pmsm::test
