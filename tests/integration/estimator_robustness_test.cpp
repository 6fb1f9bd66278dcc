// The estimator away from the reference heat-up (issue: any motor, any ambient, warm
// restarts): the robustness suite's scenarios of bench/scenarios/robustness, closed loop.
//
// Bounds from the physics, with room above what these runs measure (docs/accuracy.md):
//   - a resistance resolved to about 1 % is 2.6 C of copper (Eq. 1: 1 / alpha(T0) = K + T0);
//   - Eq. 1 with one alpha at every T0 (the old conversion) reads a rise from -20 C
//     (4.66e-3 / 3.93e-3 - 1) = 19 % too large: about +11 C at the 60 K rise of that run,
//     so a mean error under 1.5 C excludes it;
//   - a filter started at the calibration's T0 on a motor at 90 C read 10-65 C low for
//     minutes: a max error under 6 C excludes it;
//   - at the voltage limit with a cooling path 40 % worse than modelled, a drive that skips
//     every pair there runs on its model and ends 10-14 C low (5.8 C RMS, 10.6 C max, a
//     mean of -5.1 C): field-weakening pairs measure there; their 0.7 % low reading is about
//     -2 C at these temperatures and their band carries it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <numbers>
#include <string>
#include <vector>

#include <unistd.h>

#include "calibration_file.hpp"
#include "runner.hpp"
#include "scratch_dir.hpp"

namespace pmsm::app {
namespace {

const std::filesystem::path kSuite = std::filesystem::path(PMSM_SOURCE_DIR) / "bench/scenarios/robustness";

SimulationResult run(const std::filesystem::path& file) {
  RunOptions o;
  o.twin_for_disturbance = false;
  return run_scenario(load_scenario(file.is_absolute() ? file : kSuite / file), o);
}

// Every pair of a run, whatever its outcome.
std::uint32_t total_pairs(const SimulationResult& r) {
  std::uint32_t pairs = 0;
  for (const std::uint32_t n : r.pairs) {
    pairs += n;
  }
  return pairs;
}

// A scenario of tests/integration/data.
SimulationResult run_data(const char* file) {
  return run(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data" / file);
}

// The same scenario of tests/integration/data on several noise seeds (0: the file's own).
std::vector<SimulationResult> run_data_seeds(const char* file, std::initializer_list<std::uint64_t> seeds) {
  std::vector<SimulationResult> out;
  for (const std::uint64_t seed : seeds) {
    Scenario scenario = load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data" / file);
    if (seed != 0U) {
      scenario.plant.simulation.seed = seed;
    }
    RunOptions o;
    o.twin_for_disturbance = false;
    out.push_back(run_scenario(scenario, o));
  }
  return out;
}

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

TEST(EstimatorRobustness, CalibrationAtMinus20CReadsTheRiseRight) {
  const SimulationResult r = run("cal-minus20.toml");
  ASSERT_TRUE(r.calibrated);
  // Copper at -20 C: 0.133 ohm x (234.5 - 20) / (234.5 + 25).
  EXPECT_NEAR(r.calibration.rs0_ohm / (0.133 * 214.5 / 259.5), 1.0, 0.015);
  EXPECT_NEAR(r.calibration.t0_C, -20.0, 0.01) << "calibrated at the ambient sensor's temperature";
  // The bridge's voltage its events learned with Rs0 is kept with it (the plant's 1 us x 10 kHz
  // x 650 V + 1 V = 7.5 V; the prior the drive started from, 5.85 V).
  EXPECT_GT(r.calibration.vx_std_V, 0.0);
  EXPECT_LT(r.calibration.vx_std_V, 0.1);
  EXPECT_NEAR(r.calibration.vx_V, 7.5, 0.1);
  ASSERT_GT(r.max_winding_true_C, 60.0) << "the scenario no longer heats the winding";
  ASSERT_GT(r.winding_error_samples, 500U);
  EXPECT_LT(r.winding_error_rms_C, 2.5);
  EXPECT_LT(std::abs(r.winding_error_mean_C), 1.5);
  EXPECT_GE(r.coverage_2sigma, 0.9);
  // The report says how wide the band was (a coverage of 100 % says little of a wide one).
  EXPECT_GT(r.band_2sigma_mean_C, 0.0);
  EXPECT_LE(r.band_2sigma_mean_C, r.band_2sigma_max_C);
}

TEST(EstimatorRobustness, AWarmRestartIsReadWarmFromTheFirstMeasurement) {
  const SimulationResult r = run("warm-restart.toml");
  EXPECT_FALSE(r.calibrated) << "a warm motor must not be calibrated";
  ASSERT_GT(r.winding_error_samples, 500U);
  EXPECT_LT(r.winding_error_max_C, 6.0);
  EXPECT_LT(r.winding_error_rms_C, 2.5);
  EXPECT_GE(r.coverage_2sigma, 0.9);
}

// A recalibration asked for at power-up on a warm motor without a stored thermal state: the
// filter has measured nothing when it starts, so the request's guard passes; the calibration's
// Rs0, read through the stored calibration (Eq. 1), puts the winding about 65 K above the
// ambient sensor it would be referred to. Accepted, every later estimate read that much low
// (a newcomer's press at 70 C: 34.6 C RMS low, the truth never inside the band). Refused
// (winding_warm): the stored calibration stays, and the filter starts again from the
// temperature it reads, so the run is read as the warm restart without a recalibration is.
TEST(EstimatorRobustness, AWarmRecalibrationIsRefusedByTheStoredCalibration) {
  const SimulationResult r = run_data("warm-recalibration-short.toml");
  EXPECT_FALSE(r.calibrated) << "a warm winding must not become T0";
  ASSERT_EQ(r.calibration_failure, core::CalibrationFailure::kWindingWarm);
  // Eq. 1 with the stored 0.13238 ohm at 25 C: the winding's 90 C is 65 K above the sensor.
  EXPECT_GT(r.calibration_failure_winding_rise_C, 50.0);
  EXPECT_LT(r.calibration_failure_winding_rise_C, 75.0);
  ASSERT_GT(r.winding_error_samples, 500U);
  EXPECT_LT(r.winding_error_max_C, 6.0);
  EXPECT_LT(r.winding_error_rms_C, 2.5);
  EXPECT_GE(r.coverage_2sigma, 0.9);
}

// Pairs that never reverse the current vector (unipolar) learn no Vx: a warm restart's every
// estimate rests on the stored calibration's. Before the calibration kept it, the drive fell
// back to the configured prior (5.85 +- 3 V against the bridge's 7.5 V): these 40 s read
// 25.1 / 61.3 C RMS / max, and the full run 36 C high on average.
TEST(EstimatorRobustness, AUnipolarWarmRestartTakesTheBridgeVoltageFromItsCalibration) {
  const SimulationResult r = run_data("warm-restart-unipolar.toml");
  EXPECT_FALSE(r.calibrated);
  ASSERT_GT(r.winding_error_samples, 500U);
  ASSERT_GT(r.estimates_accepted, 20U);
  EXPECT_LT(r.winding_error_max_C, 6.0);
  EXPECT_LT(std::abs(r.winding_error_mean_C), 1.5);
  EXPECT_GE(r.coverage_2sigma, 0.9);
}

// Without a stored Vx the error of the held prior is common to every estimate: the filter must
// not average it away. Its band then holds the truth (before: 45 % of these 100 s, with the
// estimate 21 C high on average; the estimate is as far off now, and says so). The band is wide
// (its sigma grows to about 90 C here): honest, and what the daemon's start-up warning is for.
TEST(EstimatorRobustness, AHeldBridgeVoltageIsASharedErrorInTheBand) {
  const SimulationResult r = run_data("warm-restart-unipolar-no-vx.toml");
  ASSERT_GT(r.winding_error_samples, 500U);
  ASSERT_GT(r.winding_error_mean_C, 10.0) << "the prior 1.65 V below the bridge's Vx no longer reads high";
  EXPECT_GE(r.coverage_2sigma, 0.9);
}

// The bridge loses its dead time's share of the bus: a Vx stored at 650 V is 0.98 V too large on
// a bus 15 % lower (1 us x 10 kHz x 97.5 V), and unipolar pairs cannot learn it. Held as
// stored, every estimate read about 25 % low: -40.9 C of mean error, 69 C max, and the band
// held the truth in none of these 40 s. Referred to the bus by the dead time the compensation
// assumes (0.9 us), a tenth of it is left (the plant's bridge has 1 us): about 0.1 V, which
// these unipolar estimates read as about 2 % of Rs, -6 C of mean (-6.25 C, max 18.97 C; since
// unipolar estimates carry the sign pattern's error as a shared one, -6.57 C, max 20.26 C).
// The bounds stand between that and the failure: the mean within 8 C, the max under a third of
// the failure's.
TEST(EstimatorRobustness, AStoredBridgeVoltageFollowsTheBus) {
  const SimulationResult r = run_data("warm-restart-unipolar-bus-low.toml");
  EXPECT_FALSE(r.calibrated);
  ASSERT_GT(r.winding_error_samples, 500U);
  ASSERT_GT(r.estimates_accepted, 20U);
  EXPECT_LT(std::abs(r.winding_error_mean_C), 8.0);
  EXPECT_LT(r.winding_error_max_C, 69.0 / 3.0);
  EXPECT_GE(r.coverage_2sigma, 0.9);
}

// A bus that steps within an event (650 -> 800 V, the dead time commissioned 25 % short): each
// period's voltage is referred to the nominal bus with a slope no event has taught yet, 0.375 V
// off after the step. An event whose recordings lie on both sides of it may not learn Vx from
// them, and a pair whose two recordings do carries what the slope's uncertainty can make of the
// move in its error bar and its event's. Before, such an event learned a wrong Vx with a narrow
// bar, and it and the events after it read 1-22 % low (4-12 sigma; with the step 0.06 s into
// the event the next two read 22 % low). Bounds: every estimate within 3 sigma of the truth,
// the spanning event's too, and the events after it, which learn Vx and the slope on the new
// bus, within 1 % (2.6 C).
TEST(EstimatorRobustness, ABusStepWithinAnEventTeachesNoWrongVx) {
  const std::filesystem::path file = std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/bus-step-within-an-event.toml";
  for (const double step_s : {4.52, 4.56, 4.60, 4.64}) {
    Scenario s = load_scenario(file);
    s.plant.inverter.dc_source_points = {{0.0, 650.0}, {step_s, 650.0}, {step_s + 0.01, 800.0}};
    RunOptions o;
    o.twin_for_disturbance = false;
    const SimulationResult r = run_scenario(s, o);
    ASSERT_TRUE(r.calibrated) << step_s;
    int spanning = 0;
    int after = 0;
    for (const EstimateRow& e : r.estimates) {
      const double error = e.rs_est_ohm - e.rs_true_ohm;
      EXPECT_LT(std::abs(error), 3.0 * e.rs_std_ohm) << "step at " << step_s << " s, estimate at " << e.time_s << " s";
      if (e.time_s > 4.5 && e.time_s < 5.0) {
        ++spanning;
        // What --events shows for it: the spread of its recordings' buses kept it from learning.
        EXPECT_TRUE(e.vx_refused_bus_spread) << step_s;
        EXPECT_FALSE(e.vx_learning) << step_s;
        EXPECT_GT(e.bus_spread_V, 20.0) << step_s;
        EXPECT_LE(e.bus_spread_V, 150.0 + 20.0) << step_s;  // the step, and the ripple
      }
      if (e.time_s > 5.5) {
        EXPECT_LT(std::abs(error), 0.01 * e.rs_true_ohm) << "step at " << step_s << " s, estimate at " << e.time_s << " s";
        ++after;
      }
    }
    EXPECT_EQ(spanning, 1) << step_s;
    EXPECT_GE(after, 2) << step_s;
  }
}

// The compensation's dead time (0.9 us) is not the bridge's (1 us): referred to the nominal bus
// with it, a Vx learned at 650 V is 0.001 x 110 V = 0.11 V off when the supply steps to 540 V.
// Events that learn Vx on the new bus teach the second state, the slope by which Vx follows
// the bus beyond the compensation's share (InjectionConfig::vx_bus_slope_std): it comes out
// near the bridge's 0.1 % of the bus, and the estimates after it, unloaded and loaded, read
// right. Without the state the same run reads low (about 2 % unloaded while the scalar Vx
// adapts, 0.5 % loaded after it), the unsafe direction.
TEST(EstimatorRobustness, TheBridgeVoltagesShareOfTheBusIsLearned) {
  const std::filesystem::path file = std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/bus-step-short.toml";
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult with = run_scenario(load_scenario(file), o);
  Scenario off = load_scenario(file);
  off.controller.drive.injection.vx_bus_slope_std = 0.0;
  off.controller.drive.calibration_injection.vx_bus_slope_std = 0.0;
  const SimulationResult without = run_scenario(off, o);
  ASSERT_TRUE(with.calibrated);
  ASSERT_TRUE(without.calibrated);
  // (plant dead time - compensation's) x PWM frequency
  constexpr double kTrueSlope = (1.0e-6 - 0.9e-6) * 10000.0;
  EXPECT_NEAR(with.vx_bus_slope, kTrueSlope, 3.0 * with.vx_bus_slope_std);
  EXPECT_LT(with.vx_bus_slope_std, 0.5 * 0.2 * 0.9e-6 * 10000.0) << "learned: below half its prior";
  EXPECT_EQ(without.vx_bus_slope, 0.0);
  // The estimates' mean relative error on the low bus: unloaded (6-14 s) and loaded (15-24 s).
  auto mean_error = [](const SimulationResult& r, double from_s, double to_s) {
    double sum = 0.0;
    int n = 0;
    for (const EstimateRow& e : r.estimates) {
      if (e.time_s > from_s && e.time_s < to_s) {
        sum += e.rs_est_ohm / e.rs_true_ohm - 1.0;
        ++n;
      }
    }
    EXPECT_GE(n, 6) << "estimates between " << from_s << " and " << to_s << " s";
    return n > 0 ? sum / n : 0.0;
  };
  EXPECT_GT(mean_error(with, 6.0, 14.0), -0.01);
  EXPECT_LT(mean_error(without, 6.0, 14.0), -0.015) << "the step no longer shows without the slope";
  EXPECT_LT(std::abs(mean_error(with, 15.0, 24.0)), 0.003);
  EXPECT_LT(mean_error(without, 15.0, 24.0), -0.003) << "the step no longer shows without the slope";
}

// The same bus step under load (tests/integration/data/bus-step-under-load.toml): the dead time
// commissioned 0.8 us for the bridge's 1 us, the slope's error 0.002 V/V, and no event after the
// step learns Vx, so every estimate on the low bus holds Vx 0.22 V high (the bridge's loss fell
// by 1 us x 10 kHz x 110 V = 1.1 V, the compensation's referral by 0.88 V) and reads low by about
// 0.22 V / |iq| (4-8 mOhm, 10 C on average at 40-90 N m), the unsafe direction. The winding's filter learns that
// error as a state from estimates at several loads (docs/estimator.md section 4, "The bus
// slope's error, learned under load"). Bounds: the estimates on the low bus read off by at least
// 2 % on average (the case shows the bias it is about); the filter's winding over the same
// stretch within a quarter of that, as a mean; the learned error within 3 sigma of 0.002 V/V,
// its sigma below half the prior's (0.2 x 0.8 us x 10 kHz). Twice: with the nominal bus the
// calibration's (Vx known at the reference, u from it), and with control.nominal_dc_bus_V 600 V,
// 50 V below the calibration's 650 (Vx known there: u + P01 / P11 is the distance from it).
void expect_the_bus_slopes_error_learned(const Scenario& scenario) {
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(scenario, o);
  ASSERT_TRUE(r.calibrated);
  ASSERT_LT(r.calibration_time_s, 4.5) << "calibrated on the nominal bus";
  double estimate_sum_C = 0.0;
  double estimate_rel_sum = 0.0;
  int estimates = 0;
  for (const EstimateRow& e : r.estimates) {
    if (e.time_s - e.age_s > 10.0) {
      EXPECT_FALSE(e.vx_learning) << "an event under load learned Vx at " << e.time_s << " s";
      estimate_sum_C += e.winding_est_C - e.winding_true_C;
      estimate_rel_sum += e.rs_est_ohm / e.rs_true_ohm - 1.0;
      ++estimates;
    }
  }
  ASSERT_GE(estimates, 10);
  const double estimate_bias_C = estimate_sum_C / estimates;
  EXPECT_GT(std::abs(estimate_rel_sum / estimates), 0.02) << "the case no longer shows the bias it is about";
  double filter_sum_C = 0.0;
  int samples = 0;
  for (const SeriesRow& row : r.series) {
    if (row.time_s > 10.0 && row.winding_est_valid) {
      filter_sum_C += row.winding_est_C - row.winding_true_C;
      ++samples;
    }
  }
  ASSERT_GT(samples, 100);
  EXPECT_LT(std::abs(filter_sum_C / samples), 0.25 * std::abs(estimate_bias_C));
  constexpr double kTrueSlopeError = (1.0e-6 - 0.8e-6) * 10000.0;
  EXPECT_NEAR(r.bus_slope_error, kTrueSlopeError, 3.0 * r.bus_slope_error_std);
  EXPECT_GT(r.bus_slope_error_std, 0.0);
  EXPECT_LT(r.bus_slope_error_std, 0.5 * 0.2 * 0.8e-6 * 10000.0) << "learned: below half its prior";
  EXPECT_GE(r.coverage_2sigma, 0.9);
  // simulate's report says what the filter learned.
  EXPECT_NE(result_text(r).find("its error under load +0.00"), std::string::npos) << result_text(r);
}

TEST(EstimatorRobustness, TheBusSlopesErrorIsLearnedUnderLoad) {
  const std::filesystem::path data = std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data";
  {
    SCOPED_TRACE("the nominal bus the calibration's");
    expect_the_bus_slopes_error_learned(load_scenario(data / "bus-step-under-load.toml"));
  }
  {
    SCOPED_TRACE("the nominal bus 50 V below the calibration's");
    expect_the_bus_slopes_error_learned(load_scenario(data / "bus-step-under-load-nominal-600V.toml"));
  }
}

// On a 15 mH blower the machine's motoring voltage is 10-20 V above the commissioned model's
// (the bridge's error, Ke 2 % low, the EMF harmonics' ripple), more than the margin the budget
// keeps free: sized on the model, 65 of 84 pairs in these 40 s hit the voltage limit and 2
// estimates came out. Sized on the current loop's own command, most pulses fit. (A pair that
// meets the loop's limit is no longer rejected for it, docs/estimator.md section 2: what is
// counted is the pairs that met it, whatever their outcome.)
TEST(EstimatorRobustness, PulsesAreSizedOnTheVoltageTheMachineNeeds) {
  const SimulationResult r = run_data("blower-15mh-short.toml");
  ASSERT_TRUE(r.calibrated);
  const std::uint32_t pairs = total_pairs(r);
  ASSERT_GT(pairs, 40U);
  EXPECT_LT(static_cast<double>(r.pairs_on_voltage_limit), 0.4 * pairs);
  EXPECT_GE(r.estimates_accepted, 10U);
}

// A pair whose command met the current loop's voltage limit is kept: the limited command is
// applied as recorded (inside the linear modulation range), the d axis keeps its pulse and the
// fit takes the measured iq (docs/estimator.md section 2). On the crusher about half of the
// pairs meet the limit for a few periods, from the speed loop's steps rather than the pulses;
// rejected for it, as before, they left 6 estimates in these 40 s (24 now). The estimates must
// stay unbiased: their mean relative error within 1 % (2.6 C of copper). Judged over the file's
// seed and five more: the estimates of one run share their errors (the learned Lq, Vx), so one
// run's mean scatters by about 0.33 % from seed to seed (measured 2026-12-07 with `[scenario] seed`
// copies of the file on these seeds: -0.06 to -1.08 %,
// -0.49 % over the six), not by the 0.13 % that 20 independent estimates at 0.6 % would give.
TEST(EstimatorRobustness, PairsOnTheLoopsVoltageLimitAreMeasuredUnbiased) {
  const std::vector<SimulationResult> runs =
      run_data_seeds("crusher-on-voltage-limit-short.toml", {0U, 901U, 902U, 903U, 904U, 905U});
  const SimulationResult& r = runs.front();
  ASSERT_TRUE(r.calibrated);
  const std::uint32_t pairs = total_pairs(r);
  ASSERT_GT(pairs, 40U);
  ASSERT_GT(static_cast<double>(r.pairs_on_voltage_limit), 0.25 * pairs) << "the case no longer meets the limit";
  EXPECT_EQ(r.pairs[static_cast<std::size_t>(core::PairOutcome::kRejectedVoltageSaturation)], 0U)
      << "the loop's limit stays inside the bridge's linear range: nothing clips";
  EXPECT_GE(r.estimates_accepted, 16U);
  double sum = 0.0;
  int n = 0;
  for (const SimulationResult& run : runs) {
    ASSERT_TRUE(run.calibrated);
    for (const EstimateRow& e : run.estimates) {
      if (e.time_s > 13.0) {
        sum += e.rs_est_ohm / e.rs_true_ohm - 1.0;
        ++n;
      }
    }
  }
  ASSERT_GE(n, 60);
  EXPECT_LT(std::abs(sum / n), 0.01);
}

// A motor cable is measured with the winding but neither warms with it nor heats it (round 8's
// agitator: 0.0759 of its 0.408 ohm at 35 C). Told nothing, the drive reads the winding's rise
// low by the cable's share of Rs0, about 19 %: at the hottest, 30 K over the ambient, 5.6 C.
// Told the cable (motor.cable_resistance_ohm, 3 % high), it reads as the same machine without
// one (0.24 / 0.71 C over the whole file), the cable's error a few hundredths of a degree.
TEST(EstimatorRobustness, AMotorCableTheDriveIsToldOfReadsTheWindingsRise) {
  const SimulationResult told = run_data("agitator-cable-commissioned-short.toml");
  const SimulationResult untold = run_data("agitator-cable-short.toml");
  ASSERT_TRUE(told.calibrated);
  ASSERT_TRUE(untold.calibrated);
  const double rise_K = untold.max_winding_true_C - 35.0;
  ASSERT_GT(rise_K, 20.0) << "the batch no longer heats the winding";
  const double share = 0.0759 / (0.320 * (234.5 + 35.0) / (234.5 + 25.0) + 0.0759);
  EXPECT_LT(untold.winding_error_mean_C, -1.5);
  EXPECT_GT(untold.winding_error_max_C, 0.7 * share * rise_K) << "the cable's share of the rise, read low";
  EXPECT_LT(told.winding_error_rms_C, 1.0);
  EXPECT_LT(std::abs(told.winding_error_mean_C), 0.6);
  // The resistances are the same in both: only Eq. 1's conversion differs.
  EXPECT_LT(std::abs(told.rs_error_mean_pct), 0.5);
  EXPECT_LT(std::abs(untold.rs_error_mean_pct), 0.5);
}

// The same periods on a bridge whose 3.5 us dead time the extreme duties cannot lose (0.035 of
// the period against 0.025 from the rails): the bridge does not apply those commands, and the
// pairs that recorded one are rejected (rejected_voltage_saturation), not kept as above.
TEST(EstimatorRobustness, PeriodsTheBridgeCannotApplyRejectTheirPairs) {
  const SimulationResult r = run_data("crusher-long-dead-time-short.toml");
  ASSERT_TRUE(r.calibrated);
  ASSERT_GT(r.pairs_on_voltage_limit, 20U) << "the case no longer meets the limit";
  const std::uint32_t rejected = r.pairs[static_cast<std::size_t>(core::PairOutcome::kRejectedVoltageSaturation)];
  EXPECT_GT(static_cast<double>(rejected), 0.5 * static_cast<double>(r.pairs_on_voltage_limit));
}

// Lq learning takes a pair's ohmic voltage Rs <id> out of its d-axis means. With the pair's own
// Rs, a field-weakening pair's error fed the Lq it then was refitted with: an IPM's first such
// events (at 17.7 s, heating under load) read 9 % high with a 1.5 % error bar, and the filter
// jumped 10-13 C above the truth on every seed (these 30 s: 3.8-5.4 C RMS, max 10.0-12.7 C,
// coverage 76-89 % over the file's seed and 9001-9004). With the filter's resistance, whose
// error is a fraction of a pair's and not the pair's own, the same runs read 0.6-1.3 C RMS,
// max 1.4-4.8 C (docs/estimator.md section 5.1). Three seeds: each must stay far from the old
// failure (max < 8 C), the median inside RMS < 2.5 C.
TEST(EstimatorRobustness, LqLearningTakesTheFiltersResistanceNotThePairs) {
  const std::vector<SimulationResult> runs = run_data_seeds("ipm-traction-fw-short.toml", {0U, 9001U, 9002U});
  std::vector<double> rms;
  for (const SimulationResult& r : runs) {
    ASSERT_TRUE(r.calibrated);
    ASSERT_GT(r.winding_error_samples, 500U);
    EXPECT_LT(r.winding_error_max_C, 8.0);
    rms.push_back(r.winding_error_rms_C);
  }
  EXPECT_LT(median(rms), 2.5);
}

// A pair holds the field weakening's d current where it started, so that its two recordings
// share one motoring point, while its -F pulses weaken the field further. On the reversing
// salient servo of unseen round 5, with a torque budget of 0.5 N m (a tenth of its rated
// torque) and the shaft accelerating at 1000 rad/s^2 into field weakening, the pulse ramping
// off left the held id short of what the speed had come to need: the current loop lost the
// machine to its EMF, above the bus, and the drive tripped on over-current (5.96 s into seed
// 100, 9.99 s into seed 101). The drive now follows the motoring point's voltage through each
// pair and ends the pair where that voltage would eat half the regulator's reserve, the
// regulator taking the pulse's d current over (DriveController::weaken_field). Nothing trips,
// and the pairs it ended are counted as aborted.
TEST(EstimatorRobustness, APairEndsBeforeTheHeldFieldWeakeningFallsShortOfTheSpeed) {
  std::uint32_t aborted = 0;
  for (const SimulationResult& r : run_data_seeds("salient-servo-fw-reversals.toml", {0U, 100U, 101U})) {
    ASSERT_TRUE(r.calibrated);
    const SimulationResult::FaultSeen* first = r.first_fault();
    EXPECT_EQ(first, nullptr) << core::to_string(r.fault_code(*first)) << " at " << first->first_s << " s";
    aborted += r.pairs[static_cast<std::size_t>(core::PairOutcome::kAborted)];
    EXPECT_GT(r.pairs[static_cast<std::size_t>(core::PairOutcome::kAccepted)], 20U);
  }
  EXPECT_GT(aborted, 0U);
}

// A pulse is sized at its pair's start for the motoring current then; the speed loop may take
// the motoring current to the drive's limit during the pair (a set-point step, a load). On the
// 48 V servo stepping 150 <-> 250 rad/s under 3.5 N m the sum reached 54.07 A against the
// sensors' 54 A trip, 10.58 s into seeds 7, 8 and 9 (over-current, then the shaft ran away:
// overspeed). The scheduler now keeps the sum within the limit: a pulse crowded a little is cut,
// one crowded more ends its pair.
TEST(EstimatorRobustness, APulseNeverTakesTheCurrentPastTheLimit) {
  std::uint32_t aborted = 0;
  for (const SimulationResult& r : run_data_seeds("servo48-steps-at-the-current-limit.toml", {7U, 8U, 9U})) {
    ASSERT_TRUE(r.calibrated);
    const SimulationResult::FaultSeen* first = r.first_fault();
    EXPECT_EQ(first, nullptr) << core::to_string(r.fault_code(*first)) << " at " << first->first_s << " s";
    aborted += r.pairs[static_cast<std::size_t>(core::PairOutcome::kAborted)];
  }
  EXPECT_GT(aborted, 0U);
}

// The angle check's and the bridge sweep's levels run on top of the held motoring point. Asked to
// calibrate at 600 rad/s in field weakening, a servo's check put +3.7 A of d current on top of
// the held -12.5 A, the current loop lost the machine to its EMF and the bridge tripped 5 ms later
// (8.005 s, three seeds). Now both end as voltage-limited before their first level and nothing
// trips; the calibration's events wait for headroom.
TEST(EstimatorRobustness, NoCommissioningLevelRunsInFieldWeakening) {
  for (const SimulationResult& r : run_data_seeds("servo-calibration-in-field-weakening.toml", {0U, 2U, 3U})) {
    const SimulationResult::FaultSeen* first = r.first_fault();
    EXPECT_EQ(first, nullptr) << core::to_string(r.fault_code(*first)) << " at " << first->first_s << " s";
    EXPECT_EQ(r.angle_check.outcome, core::AngleCheckOutcome::kVoltageLimited);
    EXPECT_NEAR(r.angle_check_time_s, 8.0, 0.01);
    EXPECT_EQ(r.inverter_sweep.outcome, core::InverterSweepOutcome::kVoltageLimited);
  }
}

// A positive d level (a pair's +F, the angle check's +L) raises the machine's voltage; a bus that
// sags while it is on can leave the loop unable to hold it, below the field-weakening speed too.
// Held there, the loop keeps its d current and loses the q current: on round 5's fan the bridge
// tripped 37-40 ms after the sag began (seeds 1-3, in a pair and in the calibration's check). A
// positive level held on the voltage limit for 2 ms now ends: the pair aborted, the check
// voltage-limited.
TEST(EstimatorRobustness, APositiveLevelHeldOnTheVoltageLimitEnds) {
  for (const SimulationResult& r : run_data_seeds("fan-bus-sag-during-a-pulse.toml", {1U, 2U, 3U})) {
    const SimulationResult::FaultSeen* first = r.first_fault();
    EXPECT_EQ(first, nullptr) << core::to_string(r.fault_code(*first)) << " at " << first->first_s << " s";
    EXPECT_GT(r.pairs[static_cast<std::size_t>(core::PairOutcome::kAccepted)], 5U);
  }
  for (const SimulationResult& r : run_data_seeds("fan-bus-sag-during-the-angle-check.toml", {1U, 2U, 3U})) {
    const SimulationResult::FaultSeen* first = r.first_fault();
    EXPECT_EQ(first, nullptr) << core::to_string(r.fault_code(*first)) << " at " << first->first_s << " s";
    EXPECT_EQ(r.angle_check.outcome, core::AngleCheckOutcome::kVoltageLimited);
  }
}

// A field-weakening event dates its Rs some 3 recordings' spacings after its second recording.
// The drive holds it until the filter's clock reaches that time, and the filter compares it
// with the line through its own trajectory that the pairs extrapolate along
// (DriveController::hold_estimate). Referred back by the model's rate of warming instead, a
// salient servo's estimates read 4.7 mOhm (0.7 %) low on average while it heated, the model's
// rate being 30-80 % above the winding's. Each published estimate is at least as old as its
// time (a held one by up to one thermal update, 10 ms); one fused before its time would show an
// age of 0. Held, the estimates' mean error at their own time is within 3 mOhm over three
// seeds (70-90 of them, 11-15 mOhm RMS each: a standard error of 1.3-1.6 mOhm). (A bound of
// 5 C on one seed's largest winding error was a draw: 3.5-5.4 C over seeds 901-906, and 6.3 C on
// the file's own once repeated refusals were jittered, docs/accuracy.md. The build before the
// cooling path's error was learned read 7.4, 7.4 and 3.1 C (6.3, 6.5, 3.2 on an older one);
// since, 6.8, 8.4 and 2.9 C, their RMS lower on each: 3.6, 3.2, 1.4 C from 4.0, 3.5, 1.6. Seed
// 901's largest error is the model's heating 18 s in, with g still near 0 (-0.01): the fifth
// state's variance moved the gains, not its value.)
TEST(EstimatorRobustness, AFieldWeakeningEstimateWaitsForItsTime) {
  double error_sum_ohm = 0.0;
  int fused_held = 0;
  for (const SimulationResult& r : run_data_seeds("salient-servo-fw-short.toml", {0U, 901U, 902U})) {
    ASSERT_TRUE(r.calibrated);
    int held = 0;
    int early = 0;
    for (const EstimateRow& e : r.estimates) {
      const bool is_held = e.age_s > 0.0 && e.age_s <= 0.0105;
      held += is_held ? 1 : 0;
      early += e.age_s <= 0.0 ? 1 : 0;
      if (is_held && e.fused && std::isfinite(e.rs_true_ohm)) {
        error_sum_ohm += e.rs_est_ohm - e.rs_true_ohm;
        ++fused_held;
      }
    }
    EXPECT_GT(held, 20);
    EXPECT_EQ(early, 0);
    EXPECT_LT(r.winding_error_max_C, 10.0);  // a sanity bound on each seed (6.8, 8.4, 2.9 C)
  }
  ASSERT_GT(fused_held, 60);
  EXPECT_LT(std::abs(error_sum_ohm / fused_held), 3e-3) << "mean error " << error_sum_ohm / fused_held << " ohm";
}

// Fixed-angle pulses turn in the rotor frame: at light load their events learn Vx from the
// pairs' whole-turn means, but take Rs from the sample fit. Conditioned on the means fit
// instead, their Rs carried an error bar of 40 mOhm (30 %) against errors of 2 mOhm, and a warm
// restart's filter, starting from the ambient sensor, ignored them: these 40 s read 19.9 /
// 61.2 C RMS / max before the calibration kept Vx, and the whole run a max of 56 C with it.
//
// Five noise seeds, not one: at 157 rad/s and 60 Nm these estimates read 1.5-3 % high, and
// whether one of them comes with a narrow error bar (and pulls the band off the truth) is a
// draw. Over seeds 606-613 the band held the truth >= 90 % of the time on 5 of 8 before the
// speed ramp (control.speed_ramp_rad_s2) changed the trajectories and on 7 of 8 after it
// (docs/accuracy-journal.md, twentieth session); every max stayed under 9.5 C. So every seed
// must stay far from the old failure (max < 10 C), and the median seed inside RMS < 4 C and
// coverage >= 90 %.
TEST(EstimatorRobustness, AFixedAngleWarmRestartTakesItsLightLoadEvents) {
  const std::initializer_list<std::uint64_t> seeds{606U, 607U, 608U, 609U, 610U};
  std::vector<double> rms;
  std::vector<double> coverage;
  auto seed = seeds.begin();
  for (const SimulationResult& r : run_data_seeds("warm-restart-fixed-angle.toml", seeds)) {
    ASSERT_GT(r.winding_error_samples, 500U) << "seed " << *seed;
    EXPECT_LT(r.winding_error_max_C, 10.0) << "seed " << *seed;
    rms.push_back(r.winding_error_rms_C);
    coverage.push_back(r.coverage_2sigma);
    ++seed;
  }
  EXPECT_LT(median(rms), 4.0);
  EXPECT_GE(median(coverage), 0.9);
}

TEST(EstimatorRobustness, AtTheVoltageLimitFieldWeakeningPairsMeasure) {
  const SimulationResult r = run("rated-speed-poor-cooling.toml");
  ASSERT_TRUE(r.calibrated);
  ASSERT_GT(r.max_winding_true_C, 100.0) << "the scenario no longer heats the winding";
  ASSERT_GT(r.winding_error_samples, 500U);
  // 170 s at rated speed, one event a second: most of them measure.
  EXPECT_GT(r.field_weakening_pairs_accepted, 150U);
  EXPECT_GT(r.estimates_accepted, 100U);
  EXPECT_LT(r.winding_error_max_C, 8.0);
  EXPECT_LT(r.winding_error_rms_C, 4.5);
  EXPECT_GT(r.winding_error_mean_C, -4.0);
  EXPECT_GE(r.coverage_2sigma, 0.9) << "the band carries the pairs' shared error";
}

// A light salient rotor: a pulse's reluctance torque, 1.5 p (Ld - Lq) id iq, accelerates the
// shaft one way in a pair's first recording and the other way in its second. The PLL's angle
// lags an acceleration a by a / wn^2 (0.016 rad electrical here), and its speed enough to leave
// the command about 1e-3 rad off the rotor's axis: a bridge pattern projected in the PLL's frame
// took Vx Gq times the lag into dGd, a command taken in the frame it was planned in took
// w psi_q times the gap into dVd, and both change sign with Ld - Lq. Together they read these
// probes 1.5 % low and, with Ld and Lq swapped, 1.5 % high; with the pattern in the rotor's
// frame and the command still in the planned one, -0.25 % and +0.05 %; now -0.09 % and -0.09 %
// (docs/estimator.md section 5.5). Physics says the bias must not follow the sign of Ld - Lq:
// the two probes must agree within 0.15 % (each half of the old bias moved them 3.1 % and
// 0.30 % apart), and each read within 0.3 % (a round rotor's residual is -0.12 %).
//
// Five noise seeds: the two probes' means differ from seed to seed by up to 0.2 % on their own
// (2026-11-30, torque-neutral pulses: 0.20, 0.05, 0.00, 0.08, 0.02 % over the file's seed and
// 901-904; without those pulses 0.15, 0.00, -0.03, 0.09, 0.00 %), so one seed's difference does
// not tell a bias that follows Ld - Lq from noise: the median must stay within 0.15 %, and
// every run within 0.3 %.
TEST(EstimatorRobustness, ALightSalientRotorsPulsesDoNotTurnTheFrame) {
  const std::initializer_list<std::uint64_t> seeds{0U, 901U, 902U, 903U, 904U};
  const std::vector<SimulationResult> lq_above = run_data_seeds("servo-salient-probe.toml", seeds);
  const std::vector<SimulationResult> ld_above = run_data_seeds("servo-salient-probe-swapped.toml", seeds);
  std::vector<double> difference;
  for (std::size_t k = 0; k < lq_above.size(); ++k) {
    for (const SimulationResult* r : {&lq_above[k], &ld_above[k]}) {
      ASSERT_TRUE(r->calibrated) << r->scenario << " run " << k;
      ASSERT_GT(r->estimates_accepted, 12U) << r->scenario << " run " << k;
      EXPECT_LT(std::abs(r->rs_error_mean_pct), 0.3) << r->scenario << " run " << k;
    }
    difference.push_back(lq_above[k].rs_error_mean_pct - ld_above[k].rs_error_mean_pct);
  }
  EXPECT_LT(std::abs(median(difference)), 0.15) << "the estimates follow the sign of Ld - Lq";
}

// A salient machine's unloaded calibration (Lq = 1.5 Ld, commissioned 10 % low; 60 rad/s, F =
// 20 A): even the friction's current makes the speed loop answer each pulse's reluctance torque
// with a diq proportional to the injection, which Eq. 37 weighs with Lq. Its Lq <w iq> is about
// 1.5 V, and with the commissioned Lq Rs0 read 1.39 % low (-0.89 to -1.32 % on four other
// seeds; -0.50 % with the injection's Lq exact), +6.5 C of mean error for the whole benchmark.
// Learned within the calibration, Lq is right to 1 % and Rs0 is left with the no-load bias every
// calibration has (-0.2 to -0.5 % on the reference's seeds) and an F = 20 A calibration's
// noise (about 0.3 %): within 0.8 %, which the commissioned Lq's error alone exceeds. (Its
// pulses stay on the d-axis: the calibration has no torque-neutral pulses.)
TEST(EstimatorRobustness, ASalientMachinesUnloadedCalibrationLearnsLq) {
  const SimulationResult r = run_data("salient-calibration.toml");
  ASSERT_TRUE(r.calibrated);
  EXPECT_NEAR(r.lq_H, 8.25e-3, 0.01 * 8.25e-3);
  EXPECT_LT(std::abs(r.calibration_rs0_error_pct), 0.8);
}

// A salient machine that stays at one load never resolves its Lq curve's slope: its pairs
// measure the secant there, and the fit needs the incremental for the speed loop's answer to
// the reluctance torque (docs/estimator.md section 5.1). On the 30 mohm IPM at 314 rad/s and
// 75 A the gap is 3.4 % of Lq, and w diq (secant - incremental) / (Rs dId) reads Rs about 6 %
// high without it: some 18 C at 70 C (Eq. 1: 6 % of K + T). The flux map (six points, -5 % on
// every Lq figure) gives the gap to its own error, 5 % of the gap: about 0.3 %, and a residual
// of +0.2 % with the map exact (docs/estimator.md section 5.1) leaves some 0.5 % of 234.5 + 70 K,
// 1.5 C: the mean and the RMS within 2 C. The map's rated-current point alone gives the
// quadratic through it, whose gap at 75 A is 10 % short of the map's: at 6 % of Rs for the
// whole gap that predicts 0.6 % more, 0.35 % measured (the sensitivity differs between kinds
// of gap error, 0.035-0.07 % per 1 %, docs/estimator.md section 5.1): the test asks at least
// 0.15 % higher than the map.
TEST(EstimatorRobustness, ACruisingIpmTakesItsSaturationFromTheFluxMap) {
  const std::filesystem::path data = std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data";
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult map = run_scenario(load_scenario(data / "ipm-cruise-short.toml"), o);
  ASSERT_TRUE(map.calibrated);
  ASSERT_GT(map.max_winding_true_C, 60.0) << "the scenario no longer heats the winding";
  ASSERT_GT(map.estimates_accepted, 30U) << "pairs measure at 314 rad/s";
  EXPECT_LT(std::abs(map.winding_error_mean_C), 2.0);
  EXPECT_LT(map.winding_error_rms_C, 2.0);
  EXPECT_GE(map.coverage_2sigma, 0.9);
  const SimulationResult point = run_scenario(load_scenario(data / "ipm-cruise-short-one-point.toml"), o);
  ASSERT_GT(point.estimates_accepted, 30U);
  EXPECT_GT(point.rs_error_mean_pct - map.rs_error_mean_pct, 0.15)
      << "the map's shape gives the incremental Lq that its rated point's quadratic misses";
  const SimulationResult none = run_scenario(load_scenario(data / "ipm-cruise-short-no-map.toml"), o);
  ASSERT_GT(none.estimates_accepted, 30U);
  EXPECT_GT(none.winding_error_mean_C, 7.5) << "without the map the secant stands for the incremental";
}

// A Ke0 in the wrong units (per electrical rad/s): every EMF reading lies far outside what a
// magnet can be. Each is refused and counted with its reason, no magnet estimate is ever
// published (so none derates the drive), and the winding's estimate, which does not use Ke0,
// is unaffected.
TEST(EstimatorRobustness, EmfReadingsAgainstAWrongKe0AreRefused) {
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(
      load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/ke0-per-electrical-rad.toml"), o);
  ASSERT_GT(r.estimates_accepted, 10U) << "the events measure";
  EXPECT_GE(r.magnet_rejected, r.estimates_accepted) << "every event's EMF reading is refused";
  EXPECT_EQ(r.magnet_last_refusal, core::MagnetRefusal::kImplausible);
  // Eq. 3: Ke / Ke0 = 3, so 25 C + (3 - 1) / -0.0012 per C.
  EXPECT_LT(r.magnet_last_refused_C, -1000.0);
  EXPECT_EQ(r.magnet_error_samples, 0U) << "no magnet estimate was ever valid";
  EXPECT_LT(r.winding_error_rms_C, 2.5);
}

// A calibration that cannot learn the bridge's voltage is refused, not stored: its Rs0 would
// have been 55 % high (every later reading about 100 C low), and its own standard error says
// so (26 % of Rs0 against the 2 % allowed).
TEST(EstimatorRobustness, ACalibrationThatCannotLearnTheBridgeIsRefused) {
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r =
      run_scenario(load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/calibration-at-speed.toml"), o);
  EXPECT_FALSE(r.calibrated);
  ASSERT_EQ(r.calibration_failure, core::CalibrationFailure::kUncertain);
  EXPECT_GT(r.calibration_failure_rs0_std_ohm, 0.02 * r.calibration_failure_rs0_ohm);
  EXPECT_LT(r.calibration_failure_time_s, 5.0) << "refused when its events are in, not at the timeout";
}

TEST(EstimatorRobustness, AOnePointSixOhmServoCalibratesAndIsTracked) {
  const SimulationResult r = run("servo-1p6ohm.toml");
  ASSERT_TRUE(r.calibrated) << "the defaults are relative to the motor: the window fits 1.6 ohm";
  EXPECT_NEAR(r.calibration.rs0_ohm / 1.6, 1.0, 0.02);
  ASSERT_GT(r.max_winding_true_C, 80.0);
  EXPECT_GT(r.estimates_accepted, 50U);
  EXPECT_LT(r.winding_error_rms_C, 3.5);
  EXPECT_LT(r.winding_error_max_C, 9.0);
  // The servo's Lq is 7.2 mH at every current (no saturation in this plant). Read as count n
  // alone, the truncating encoder left the drive half a count behind the rotor; the frame's
  // rotation put -delta w psi_m into <vd> and the learned Lq read 7.39 mH at zero current and
  // 15 % less at the current limit, a curve the machine does not have.
  EXPECT_NEAR(r.lq_H / 7.2e-3, 1.0, 0.015);
  EXPECT_NEAR((r.lq_H - r.lq_saturation_H) / 7.2e-3, 1.0, 0.06);
}

// An encoder 1.5 degrees electrical off its commissioned offset: every d-axis pulse then has
// F sin(1.5 deg) of torque-producing current (1.9 Nm at the calibration's 50 A), the speed loop
// answers it between a pair's recordings, and without the rotor-angle check the calibration
// times out (its pairs rejected for the speed change). The check measures the offset from the
// q current the speed loop needs against +-25 A of d current (docs/estimator.md section 6.1):
// its error is the speed loop's residue and the noise, hundredths of a degree here.
TEST(EstimatorRobustness, AnEncoderOffsetIsCheckedAndCorrectedByTheCalibration) {
  Scenario s = load_scenario(kSuite / "encoder-offset.toml");
  s.scenario.duration_s = 40.0;  // the calibration and the first loaded spells
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(s, o);
  ASSERT_TRUE(r.calibrated);
  ASSERT_EQ(r.angle_check.outcome, core::AngleCheckOutcome::kMeasured) << core::to_string(r.angle_check.outcome);
  const double truth_rad = -1.5 * std::numbers::pi / 180.0;
  EXPECT_NEAR(r.angle_correction_rad, truth_rad, 0.1 * std::numbers::pi / 180.0);
  EXPECT_TRUE(r.calibration.angle_correction_measured);
  EXPECT_DOUBLE_EQ(r.calibration.angle_correction_rad, r.angle_correction_rad) << "stored with the calibration";
  ASSERT_GT(r.winding_error_samples, 300U);
  EXPECT_LT(r.winding_error_rms_C, 2.0);
  EXPECT_LT(r.winding_error_max_C, 5.0);
  EXPECT_GE(r.coverage_2sigma, 0.9);

  s.controller.drive.angle_check.enabled = false;
  const SimulationResult unchecked = run_scenario(s, o);
  EXPECT_FALSE(unchecked.calibrated) << "without the check the offset fails the calibration (what the check is for)";
  // And says why: at its timeout the few events it has (one pair each, which cannot learn the
  // bridge's voltage) give an Rs0 too uncertain to take; its pairs, rejected for the speed loop's
  // answer to the offset's torque.
  ASSERT_EQ(unchecked.calibration_failure, core::CalibrationFailure::kUncertain);
  EXPECT_GE(unchecked.calibration_failure_events, s.controller.drive.calibration_min_events);
  EXPECT_LT(unchecked.calibration_failure_events, s.controller.drive.calibration_events);
  const auto& pairs = unchecked.calibration_failure_pairs;
  const auto speed_change = pairs[static_cast<std::size_t>(core::PairOutcome::kRejectedSpeedChange)];
  EXPECT_GT(speed_change, 0U);
  EXPECT_EQ(core::pair_outcomes_text(pairs).rfind(std::to_string(speed_change) + " rejected_speed_change", 0), 0U)
      << core::pair_outcomes_text(pairs);
}

// An exact encoder on a heavy rotor is left as it is (docs/estimator.md section 6.1, "The speed's
// noise is a floor under its error bar"): the round-9 press (1.38 kg m^2 on a 14-bit encoder) on
// seed 9304, whose check reads +22 mrad with the levels' own error bar at 4 mrad, was corrected
// by those 22 mrad before the floor; the floor, about 11 mrad, keeps the angle in use, and
// simulate reports it.
TEST(EstimatorRobustness, AnExactEncoderOnAHeavyRotorIsNotCorrected) {
  Scenario s = load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "bench/scenarios/unseen/round9/b-press8p-1hz-strokes.toml");
  s.plant.simulation.seed = 9304;
  s.scenario.duration_s = 8.0;  // the check ends at about 3 s
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(s, o);
  ASSERT_EQ(r.angle_check.outcome, core::AngleCheckOutcome::kMeasured) << core::to_string(r.angle_check.outcome);
  const core::AngleCheckResult& a = r.angle_check;
  EXPECT_GT(std::abs(a.offset_rad), 3.0 * std::hypot(a.offset_std_rad, a.model_std_rad))
      << "the levels' own error bar would have corrected it";
  EXPECT_GT(a.speed_std_rad, a.offset_std_rad);
  EXPECT_LT(std::abs(a.offset_rad), 3.0 * std::hypot(a.speed_std_rad, a.model_std_rad));
  EXPECT_EQ(r.angle_correction_rad, 0.0) << "the encoder is exact";
}

// The 48 V servo's rotor is light (1.5e-4 kg m^2) and slightly salient (Lq - Ld = 0.02 mH): a
// pulse's reluctance torque, 3/2 p (Ld - Lq) F iq, of opposite sign in a pair's two recordings,
// moves its speed, and the speed loop pulls it back within milliseconds. Eq. 37 carries that as
// Lq iq dw. Taken from the PLL (300 rad/s), which lags such a transient, dw was wrong by opposite
// amounts in the two recordings and the loaded estimates read -0.56 % (about -1.5 C here); the
// encoder's advance over each period, the period's mean speed, reads them -0.34 to -0.41 %. The
// same machine non-salient, or 20 times heavier, reads -0.1 % (docs/estimator.md 5.4): what is
// left is not traced. The bound lies between the two, three standard errors of the mean away
// from each.
TEST(EstimatorRobustness, ALightRotorsSpeedTransientIsNotReadAsResistance) {
  Scenario s = load_scenario(kSuite / "servo-48v-20khz.toml");
  s.scenario.duration_s = 60.0;  // 100 and 200 rad/s under load, 40 rad/s and part of 250
  RunOptions o;
  o.twin_for_disturbance = false;
  o.keep_series = false;
  const SimulationResult r = run_scenario(s, o);
  ASSERT_TRUE(r.calibrated);
  double sum = 0.0;
  int n = 0;
  for (const EstimateRow& e : r.estimates) {
    if (e.fused && e.iq_A > 10.0 && e.rs_true_ohm > 0.0) {
      sum += (e.rs_est_ohm - e.rs_true_ohm) / e.rs_true_ohm;
      ++n;
    }
  }
  ASSERT_GT(n, 100);
  EXPECT_GT(sum / n, -0.0048) << "mean loaded error " << 100.0 * sum / n << " %";
  EXPECT_LT(sum / n, 0.0048) << "mean loaded error " << 100.0 * sum / n << " %";
}

// A load that comes before the calibration's end (round 6's dough mixer, loaded at 4.5 s with 4 of
// its 6 events in, the rest's pulses asking more voltage than 105 N m at 110 rad/s leaves): at its
// timeout the calibration completes on the events it has. Their Rs0 is good to their standard
// error (0.2-0.8 % for a calibration that learns the bridge's voltage, docs/estimator.md section
// 6), where the nameplate's, which the drive ran on before, is commissioned 3 % high (about 8 K).
// With calibration.min_events = 0 it gives up as before and the nameplate stays.
TEST(EstimatorRobustness, ACalibrationCutShortByALoadCompletesOnTheEventsItHas) {
  Scenario s = load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) /
                             "bench/scenarios/unseen/round6/c7b-mixer-loaded-before-calibration-done.toml");
  s.scenario.duration_s = 0.5 + s.controller.drive.calibration_timeout_s + 2.0;
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(s, o);
  ASSERT_TRUE(r.calibrated);
  EXPECT_GE(r.calibration_events, s.controller.drive.calibration_min_events);
  EXPECT_LT(r.calibration_events, s.controller.drive.calibration_events) << "the load took the last events";
  EXPECT_EQ(r.calibration_events_wanted, s.controller.drive.calibration_events);
  EXPECT_GT(r.calibration_time_s, 0.5 + s.controller.drive.calibration_timeout_s) << "completed at its timeout";
  EXPECT_NE(result_text(r).find(" of 6 events, at its timeout (calibration.min_events)"), std::string::npos) << result_text(r);
  const double nameplate_pct = 100.0 * (s.controller.drive.motor.rs_ohm / s.plant.motor.rs_at_C(s.controller.drive.motor.rs_reference_temp_C) - 1.0);
  ASSERT_GT(nameplate_pct, 2.5) << "the premise: a nameplate several kelvin off";
  EXPECT_LT(std::abs(r.calibration_rs0_error_pct), 3.0 * 100.0 * r.calibration_rs0_std_ohm / r.calibration.rs0_ohm);
  EXPECT_LT(std::abs(r.calibration_rs0_error_pct), nameplate_pct / 3.0);

  s.controller.drive.calibration_min_events = 0;
  const SimulationResult gave_up = run_scenario(s, o);
  EXPECT_FALSE(gave_up.calibrated);
  EXPECT_EQ(gave_up.calibration_failure, core::CalibrationFailure::kTimeout);
}

// A calibration at rest (time-based recordings: no EMF) measures no Ke0, and the magnets went
// unmeasured for the whole run. The drive now takes Ke0 from its first turning events while it
// knows the rotor's temperature: between the ambient and the housing's estimate, a span of a
// few kelvin in the first minutes after a soaked start, whose uncertainty (at most
// calibration.magnet_reference_max_std_C, 5 C) is in Ke0's error bar. Bounds: Ke0 within three
// of its own standard errors of the plant's at T0, and within 1 % (the rotor's 5 C are 0.6 %);
// its band holds the truth 90 % of the time; RMS and max with room above what this run
// measures (0.76 and 2.7 C; a turning calibration's magnets read about 1 C RMS on the
// reference heat-up, and the rotor's span can add up to its sigma). Ke0 is stored with the
// calibration. With the key at 0, no magnet is measured (as before).
TEST(EstimatorRobustness, ACalibrationAtRestTakesKe0FromTheFirstTurningEvents) {
  const pmsm::test::ScratchDir scratch{"pmsm-magnet-reference"};
  const std::filesystem::path& dir = scratch.path();
  const std::string file = (dir / "calibration.toml").string();
  Scenario s = load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/calibration-at-rest-short.toml");
  s.controller.calibration_file = file;
  RunOptions o;
  o.twin_for_disturbance = false;
  const SimulationResult r = run_scenario(s, o);
  ASSERT_TRUE(r.calibrated);
  EXPECT_EQ(r.angle_check.outcome, core::AngleCheckOutcome::kNotTurning) << "the premise: a calibration at rest";
  ASSERT_GT(r.magnet_reference_time_s, 4.4) << "taken once the rotor turns";
  EXPECT_EQ(r.magnet_reference_events, s.controller.drive.calibration_events);
  EXPECT_GT(r.magnet_reference_std_C, 0.0);
  EXPECT_LE(r.magnet_reference_std_C, s.controller.drive.magnet_reference_max_std_C);
  EXPECT_GE(r.magnet_reference_at_C, r.calibration.t0_C - 1.0);
  const double p = s.plant.motor.pole_pairs;
  const double ke0_true = p * plant::psi_m_from_Ke(s.plant.motor.ke_V_s_per_rad, s.plant.motor.pole_pairs) *
                          (1.0 + s.plant.motor.magnet_temp_coefficient_per_C * (r.calibration.t0_C - s.plant.motor.magnet_ref_temp_C));
  const double ke0 = r.calibration.ke0_V_s_per_rad;
  const double ke0_std = r.calibration.ke0_std_V_s_per_rad;
  ASSERT_GT(ke0_std, 0.0);
  EXPECT_NEAR(ke0, ke0_true, 3.0 * ke0_std);
  EXPECT_LT(ke0_std / ke0, 0.01);
  ASSERT_GT(r.magnet_error_samples, 1000U);
  EXPECT_LT(r.magnet_error_rms_C, 2.5);
  EXPECT_LT(r.magnet_error_max_C, 6.0);
  EXPECT_GE(r.magnet_coverage_2sigma, 0.9);
  ASSERT_TRUE(r.calibration_stored) << r.calibration_file_error;
  const core::Calibration stored = read_calibration_file(file);
  EXPECT_DOUBLE_EQ(stored.rs0_ohm, r.calibration.rs0_ohm);
  EXPECT_DOUBLE_EQ(stored.ke0_V_s_per_rad, ke0);
  EXPECT_DOUBLE_EQ(stored.ke0_std_V_s_per_rad, ke0_std);

  s.controller.calibration_file.clear();
  // Tighter than the filter ever knows its housing here (2-3 C after the calibration): the
  // rotor is never known that well, so no event qualifies.
  s.controller.drive.magnet_reference_max_std_C = 1.0;
  const SimulationResult tight = run_scenario(s, o);
  EXPECT_LT(tight.magnet_reference_time_s, 0.0);
  EXPECT_EQ(tight.magnet_error_samples, 0U);

  s.controller.drive.magnet_reference_max_std_C = 0.0;
  const SimulationResult off = run_scenario(s, o);
  ASSERT_TRUE(off.calibrated);
  EXPECT_LT(off.magnet_reference_time_s, 0.0);
  EXPECT_DOUBLE_EQ(off.calibration.ke0_V_s_per_rad, 0.0);
  EXPECT_EQ(off.magnet_error_samples, 0U) << "no Ke0, no magnet estimate";
}

}  // namespace
}  // namespace pmsm::app
