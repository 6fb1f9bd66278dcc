// The in-process closed loop: plant library + sensor front end + drive controller, lockstep,
// faster than real time; and the figures the accuracy benchmark reports (DESIGN section 9).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "pmsm/core/supervisor.hpp"
#include "scenario.hpp"

namespace pmsm::app {

// The plant's model stopped being a number (Plant::diverged): a machine its integration cannot
// follow that the plant's configuration rules did not catch. The run stops there; what it
// computed after that would be meaningless.
struct PlantDivergedError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct RunOptions {
  bool progress = false;            // a progress line on stderr (for terminals)
  // Measure speed and torque disturbance against a twin of the run without injection, forked
  // from it where each event begins (the same state, set-points and noise from there on): the
  // difference is what the injection caused.
  bool twin_for_disturbance = true;
  // The twin forks from a snapshot of the run taken between events, a few periods before each
  // scheduled event, and at most this many periods apart for the events a request starts (a
  // copy of the plant and the drive each time; a longer interval costs more catch-up from the
  // snapshot to such an event). The figures do not depend on it.
  std::uint64_t twin_snapshot_periods = 2000;
  // Step the twin on a thread of its own, beside the run (the figures are the same either way;
  // with a core to spare it costs the run's thread nothing but the snapshots' copies).
  bool twin_thread = true;
  // The twin outlives the rows the metric needs by this many (a test's check that it lives long
  // enough: the figures during injection must not change).
  std::size_t twin_extra_rows = 0;
  bool log_events = false;          // keep a line per event that published nothing
  // Keep the time series (SimulationResult::series, for a CSV or a plot) and the published
  // estimates (estimates: --events, plots). The figures do not need them: they are computed as
  // the run goes, so that a long run without these outputs takes memory bounded by the
  // scenario, not by its duration.
  bool keep_series = true;
  bool keep_estimates = true;
};

// One row of the time series, every log_period_s.
struct SeriesRow {
  double time_s = 0.0;
  double winding_true_C = 0.0;
  bool winding_est_valid = false;  // no estimate yet: not 0 C (empty in CSV, a gap in plots)
  double winding_est_C = 0.0;
  double winding_std_C = 0.0;
  double magnet_true_C = 0.0;
  double magnet_est_C = 0.0;
  double magnet_std_C = 0.0;
  bool magnet_valid = false;
  double housing_true_C = 0.0;
  double rs_true_ohm = 0.0;
  double speed_ref_rad_s = 0.0;
  double speed_rad_s = 0.0;         // true shaft speed
  double torque_Nm = 0.0;           // true electromagnetic torque
  double load_torque_Nm = 0.0;
  double dc_bus_V = 0.0;            // true DC bus (its ripple included)
  // The currents the drive measured this period; not measured (empty in CSV) when the drive used no
  // sample: a latched fault, an outage (the controller's telemetry holds its last period's then).
  bool current_valid = false;
  double id_A = 0.0;
  double iq_A = 0.0;
  double current_limit_A = 0.0;
  bool derating = false;
  bool time_to_limit_valid = false;
  double time_to_limit_s = 0.0;
  bool injection_active = false;
  bool counted = false;             // inside the error-metric window
  // What the thermal filter has learned of its model (empty in the CSV before an estimate):
  // its housing node, the missing loss dP, the copper loss's relative error k and the cooling
  // path's g.
  double housing_est_C = 0.0;
  double missing_loss_W = 0.0;
  double loss_scale_error = 0.0;
  double cooling_scale_error = 0.0;
};

struct EstimateRow {
  double time_s = 0.0;              // published
  // How long before its publication the estimate was measured (its pairs' weighted mean time,
  // EventEstimate::measured_at_s): the truth below is the plant's at that time, interpolated,
  // as the thermal filter fuses it there. NaN truth when that is older than TruthHistory keeps.
  double age_s = 0.0;
  double rs_est_ohm = 0.0;
  double rs_std_ohm = 0.0;
  double rs_true_ohm = 0.0;
  double winding_est_C = 0.0;       // Eq. 1 through the calibration
  double winding_true_C = 0.0;
  double vx_V = 0.0;
  double vx_std_V = 0.0;
  double lq_H = 0.0;
  bool vx_learning = false;
  double bus_spread_V = 0.0;          // ResistanceEstimate::bus_spread_V
  bool vx_refused_bus_spread = false;
  double joint_rs_ohm = 0.0;
  double joint_vx_V = 0.0;
  double speed_rad_s = 0.0;
  double iq_A = 0.0;
  bool fused = false;
};

struct SimulationResult {
  std::string scenario;
  std::string method;               // e.g. "fixed-magnitude bipolar", "no-injection", "none"
  core::EstimatorKind estimator = core::EstimatorKind::kInjection;  // the resistance source behind `method`
  core::SupervisorConfig supervisor{};  // the trip levels the drive ran with (the scenario's [supervisor] over the defaults)
  // Accuracy (winding: samples whose true winding temperature is above the threshold, after
  // the calibration).
  double winding_error_rms_C = 0.0;
  double winding_error_max_C = 0.0;
  double winding_error_mean_C = 0.0;
  std::size_t winding_error_samples = 0;
  double error_threshold_C = 40.0;  // the scenario's error_threshold_C (the text says it)
  // Share of the counted samples whose truth lies inside the estimate's +-2 sigma band (an
  // honest band holds about 95 %).
  double coverage_2sigma = 0.0;
  double rs_error_rms_mohm = 0.0;   // published estimates against the true Rs at that time
  // Their mean relative error (%), fused ones only: the running estimates' bias (NaN: none).
  double rs_error_mean_pct = std::numeric_limits<double>::quiet_NaN();
  // The calibration's Rs0 against the plant's resistance at the calibration's t0_C (%), by the
  // plant's own law: the calibration's bias, which Eq. 1's ratio cancels against the above.
  double calibration_rs0_error_pct = std::numeric_limits<double>::quiet_NaN();
  // Its Ke0 (a turning calibration's, or one taken from turning events after a calibration at
  // rest) against the plant's EMF constant at t0_C by the plant's own law (%): the bias every
  // magnet reading carries, 1 % about 8 C (NaN: no Ke0).
  double calibration_ke0_error_pct = std::numeric_limits<double>::quiet_NaN();
  double magnet_error_rms_C = 0.0;
  double magnet_error_max_C = 0.0;
  std::size_t magnet_error_samples = 0;
  // The band's half-width 2 sigma over the counted winding samples: a coverage of 100 % says
  // little of a band of +-20 C (a drive that measures nothing carries its model's widening band).
  double band_2sigma_mean_C = 0.0;
  double band_2sigma_max_C = 0.0;
  double magnet_coverage_2sigma = 0.0;  // of those samples, the truth inside the magnet's +-2 sigma
  std::size_t magnet_rejected = 0;      // EMF measurements the drive refused as implausible
  core::MagnetRefusal magnet_last_refusal = core::MagnetRefusal::kNone;  // why the last one was
  double magnet_last_refused_C = 0.0;   // and what it read
  std::size_t estimates_accepted = 0;   // fused by the thermal filter
  std::size_t estimates_gated = 0;      // published but gated out as implausible
  std::size_t estimates_dropped_at_restart = 0;  // held (dated after their event) when the filter restarted
  [[nodiscard]] std::size_t estimates_published() const noexcept { return estimates_accepted + estimates_gated; }
  core::OutcomeCounts pairs{};          // every pair's outcome
  std::size_t field_weakening_pairs_accepted = 0;  // of the accepted: at the voltage limit (-lo, -F)
  // Pairs that finished recording (whatever their outcome; aborted ones are not counted) with a
  // recorded command on the voltage limit (PairConditions::any_voltage_limited: the current
  // loop's, or a clipped duty): how often the budget's pulses meet it. On the loop's limit alone
  // such periods are good data; only a command the bridge could not apply rejects a pair.
  std::size_t pairs_on_voltage_limit = 0;
  // Disturbance: the largest difference from the twin without injection (forked from the run
  // where each event begins, RunOptions::twin_for_disturbance), during an injection event and
  // the disturbance window after it (speed relative to the speed, at least 10 % of rated;
  // torque relative to rated torque), and the same difference outside (what remains after the
  // window while the twin still runs; zero away from the events); both only where the twin runs
  // steadily (its speed within 0.5 % of its 50 ms moving average), so that the scenario's
  // own steps do not count.
  bool disturbance_measured = false;
  double speed_disturbance_pct = 0.0;
  double torque_disturbance_pct = 0.0;
  double speed_disturbance_mean_pct = 0.0;   // the mean over the rows judged during injection
  double torque_disturbance_mean_pct = 0.0;
  double speed_disturbance_at_s = 0.0;   // when the largest one occurred
  double torque_disturbance_at_s = 0.0;
  double speed_difference_outside_pct = 0.0;
  double torque_difference_outside_pct = 0.0;
  double injection_loss_W = 0.0;        // 3/2 Rs |i_injection|^2 averaged over the run
  double injection_duty = 0.0;          // fraction of time an event was in progress
  // Calibration.
  bool calibrated = false;
  bool calibration_running_at_end = false;  // asked for, and neither done nor failed when the run ended
  double calibration_time_s = 0.0;
  core::Calibration calibration{};
  double calibration_rs0_std_ohm = 0.0;  // the calibration's Rs0 standard error
  // The events its Rs0 averaged: calibration.events, or fewer where it completed at its timeout
  // (calibration.min_events).
  int calibration_events = 0;
  int calibration_events_wanted = 0;  // calibration.events
  int calibration_failure_events = 0;  // a refusal that measured an Rs0: the events it averaged
  // A calibration that measured no Ke0 took one from turning events later
  // (DriveController::magnet_reference_completed): when, from how many, and where the rotor was
  // taken to be (C, and its standard uncertainty); time -1: not taken.
  double magnet_reference_time_s = -1.0;
  int magnet_reference_events = 0;
  double magnet_reference_at_C = 0.0;
  double magnet_reference_std_C = 0.0;
  // A calibration run that failed (timed out, or refused an uncertain Rs0): why, when, and
  // the Rs0 it had (0 when it timed out before enough events).
  core::CalibrationFailure calibration_failure = core::CalibrationFailure::kNone;
  double calibration_failure_time_s = 0.0;
  double calibration_failure_rs0_ohm = 0.0;
  double calibration_failure_rs0_std_ohm = 0.0;
  double calibration_failure_winding_rise_C = 0.0;  // kWindingWarm: the filter's winding above the ambient
  core::OutcomeCounts calibration_failure_pairs{};  // the failed calibration's pairs, by outcome
  core::AbortCounts calibration_failure_aborts{};   // its aborted pairs, by cause
  std::string calibration_failure_detail;  // kRsOutsideWindow: what was measured and what to check (rs_outside_window_text)
  core::InverterSweepResult inverter_sweep{};  // the calibration's bridge sweep (outcome kNone: not run)
  double inverter_sweep_time_s = 0.0;
  core::AngleCheckResult angle_check{};  // the calibration's last rotor-angle check (outcome kNone: not run)
  double angle_check_time_s = 0.0;
  double angle_correction_rad = 0.0;     // the drive's rotor-angle correction at the end
  // The stored calibration (controller calibration.file): what was found at the start, and
  // whether this run's calibration was written back.
  std::string calibration_file;
  StoredCalibration calibration_at_start = StoredCalibration::kNotConfigured;
  bool calibration_stored = false;
  std::string calibration_file_error;   // the write failed: the result is in the report only
  double vx_V = 0.0;
  double vx_std_V = 0.0;
  double vx_bus_slope = 0.0;            // learned: what the compensation's dead time misses of the bus (V/V)
  double vx_bus_slope_std = 0.0;
  // The winding filter's learned error of that slope at the end (DriveController::bus_slope_error).
  double bus_slope_error = 0.0;
  double bus_slope_error_std = 0.0;
  double lq_H = 0.0;                    // learned q-axis inductance at the end
  double lq_std_H = 0.0;
  double lq_saturation_H = 0.0;         // its saturation: secant lost at the current limit
  double lq_bend_H = 0.0;               // and its bend (the secant a - b s - b2 s^2)
  std::uint32_t lq_listening_pairs = 0;    // pairs with no pulse, under a load the torque budget refused
  std::uint32_t lq_listening_learned = 0;  // those that taught the curve
  double lq_emf_d_Wb = 0.0;             // the angle error's EMF share psi delta learned with it
  double lq_emf_d_std_Wb = 0.0;
  double flux_linkage_Wb = 0.0;         // the commissioned psi, to read it as an angle
  bool lq_saturation_resolved = false;  // by pairs at two loads
  double lq_commissioned_saturation_H = 0.0;  // b0 from motor.lq_rated_H (0: none)
  // The faults the drive's supervisor latched (as its FAULT frames would show them on a bus):
  // how often each code was latched, and when first. A scenario never clears faults: after a
  // trip the drive stays off, and the figures that follow are those of a drive that is off.
  struct FaultSeen {
    std::uint32_t count = 0;
    double first_s = 0.0;
  };
  std::array<FaultSeen, core::kFaultCodeCount> faults{};
  [[nodiscard]] const FaultSeen* first_fault() const noexcept {
    const FaultSeen* first = nullptr;
    for (const FaultSeen& f : faults) {
      if (f.count > 0 && (first == nullptr || f.first_s < first->first_s)) first = &f;
    }
    return first;
  }
  [[nodiscard]] core::FaultCode fault_code(const FaultSeen& f) const noexcept {
    return static_cast<core::FaultCode>(&f - faults.data());
  }
  double max_winding_true_C = 0.0;
  double sim_time_s = 0.0;
  // Wall time of everything the scenario cost: the run, the twin without injection (for the
  // disturbance metric) and the metrics; sim_speed_ratio = sim_time_s / wall_time_s.
  double wall_time_s = 0.0;
  // The twin's own share of wall_time_s (0 without a twin), and the simulated time it ran
  // beside the run (around the events; its catch-ups from a snapshot not counted).
  double twin_wall_time_s = 0.0;
  double twin_sim_time_s = 0.0;
  std::vector<SeriesRow> series;
  std::vector<EstimateRow> estimates;
  std::array<std::uint32_t, 5> events_without_estimate{};  // by EventOutcome
  std::vector<std::string> event_log;
};

[[nodiscard]] SimulationResult run_scenario(const Scenario& scenario, const RunOptions& options = {});

// One JSON object with the figures (not the series).
[[nodiscard]] std::string result_json(const SimulationResult& r);
// A human-readable summary.
[[nodiscard]] std::string result_text(const SimulationResult& r);
// One line per published estimate (time, estimate, truth, inverter voltage, diagnostics).
[[nodiscard]] std::string estimates_text(const SimulationResult& r);
// The time series as CSV (one header line).
void write_series_csv(const SimulationResult& r, const std::string& path);
// True vs estimated winding (and magnet) temperature over time, plus speed and torque, as a
// PNG drawn by gnuplot. Throws std::runtime_error with a clear message when gnuplot fails.
void write_plot(const SimulationResult& r, const std::string& path);

}  // namespace pmsm::app
