// The controller's configuration file: the drive's commissioned motor model, sensor scaling,
// control, injection, estimator, thermal model, calibration and derating. The same sections
// configure pmsm-thermald and the [controller] part of a simulation scenario.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "toml_fwd.hpp"

#include "config_types.hpp"
#include "pmsm/core/drive_controller.hpp"

namespace pmsm::app {

// The one schema engine and its one error type (common/config_schema.hpp, config_types.hpp).
using common::at_least;
using common::between;
using common::ConfigError;
using common::ConfigSchema;
using common::positive;

// How the controller turns ADC codes into physical values: its own nominal calibration (the
// plant's gain errors stay invisible to it, as a real sensor's would).
struct SensorScaling {
  int current_adc_bits = 12;
  double current_range_A = 200.0;   // full scale is +-range
  int dc_bus_adc_bits = 12;
  double dc_bus_full_scale_V = 1000.0;
  double offset_calibration_s = 0.05;  // current-ADC offsets averaged with the gates off at start
  std::optional<double> current_noise_A;  // a sample's noise (std); absent: measured with the offsets
};

// Keys whose default follows the configured motor: absent, finalize() takes the rule of
// core::motor_relative_defaults() (which gives exactly the Table I numbers for Table I).
struct MotorRelativeKeys {
  std::optional<double> injection_f_A;
  std::optional<double> injection_f_min_A;
  std::optional<double> rs_min_ohm;
  std::optional<double> rs_max_ohm;
  std::optional<double> max_load_change_A;
  std::optional<double> calibration_f_A;
  std::optional<double> tw_s;
  std::optional<double> max_speed_change_rad_s;
  std::optional<double> speed_limit_rad_s;
  std::optional<double> speed_ramp_rad_s2;
  std::optional<double> field_weakening_max_current_A;
  std::optional<double> initial_loss_error_std_W;
  std::optional<double> loss_error_process_std_W_per_sqrt_s;
  // Follows the bus, not the motor: a share of control.nominal_dc_bus_V.
  std::optional<double> headroom_margin_V;
  std::optional<double> vx_bus_slope_std;
  // Follows the control rate above 10 kHz: kVxLearningMaxAnglePerPeriod_rad / control.period_s.
  std::optional<double> vx_learning_max_speed_rad_s;
};

// How fast an event may turn to learn the bridge's voltage Vx (injection.vx_learning_max_speed_
// rad_s): 600 electrical rad/s, or faster where the rotor still turns at most 0.06 rad in a
// control period, 105 periods an electrical turn (above 10 kHz). docs/estimator.md section 4,
// "How fast an event may learn Vx".
inline constexpr double kVxLearningMaxSpeed_rad_s = 600.0;
inline constexpr double kVxLearningMaxAnglePerPeriod_rad = 0.06;

// The pair recorder's size (core::DriveConfig::recording_capacity): the longest recording the
// injection keys ask for at the control period, within these bounds.
inline constexpr std::size_t kMinRecordingSamples = 8192;
inline constexpr std::size_t kMaxRecordingSamples = std::size_t{1} << 17;

// The share of the rated torque (RMS) the encoder's rounding may make of the speed loop's
// torque demand before the loader warns (core::speed_loop_quantisation_torque_Nm;
// docs/daemon.md, "The speed loop and the encoder").
inline constexpr double kSpeedLoopQuantisationTorqueShare = 0.05;

struct ControllerConfig {
  core::DriveConfig drive{};
  MotorRelativeKeys relative{};
  SensorScaling sensors{};
  double nominal_dc_bus_V = core::kReferenceDcBus_V;
  // The calibration procedure's injection magnitude (filled by finalize() from
  // calibration.F_A or the rated current): at no load the whole current budget is free, and a
  // larger F makes the bridge's zero-current band matter less (docs/estimator.md).
  double calibration_f_A = 50.0;
  // Unless injection.vx_initial_V is given, the inverter-error prior starts at what the
  // dead-time compensation assumes at the nominal bus voltage.
  bool vx_initial_from_compensation = true;
  // Where the calibration is kept (calibration_file.hpp): read at start-up in place of
  // calibration.rs0_ohm / t0_C / ke0_V_s_per_rad, replaced when a calibration run completes.
  // Empty: none. A relative path is relative to the configuration file.
  std::string calibration_file;
  // Where the thermal filter's state is kept across a restart (calibration_file.hpp): the
  // daemon writes it while it runs and when it stops, and restores it, cooled through the
  // downtime, when it starts. Empty: none (the filter starts from the ambient sensor).
  std::string thermal_state_file;
  // With thermal.acceleration other than 1 (a test), a calibration runs the thermal model at
  // real time, as on a machine; the plant emulator follows (THERMAL_ESTIMATE.Calibrating).
  bool calibration_real_time = true;
  // calibration.angle_correction_rad: the rotor-angle correction a calibration's angle check
  // measured (absent: none measured, sensors.encoder_offset_rad holds as configured).
  std::optional<double> angle_correction_rad;
  // motor.lq_map_current_A and motor.lq_map_H as given (finalize() checks them together and
  // fills drive.motor.lq_map).
  std::vector<double> lq_map_current_A;
  std::vector<double> lq_map_H;
};

// What became of the stored calibration at start-up.
enum class StoredCalibration : std::uint8_t {
  kNotConfigured,  // calibration.file not set: the keys (or the nameplate) hold
  kLoaded,         // read from calibration.file
  kMissing,        // calibration.file set but absent (not commissioned yet): the keys hold
};

// Loads calibration.file into config.drive.calibration when it exists. Throws
// CalibrationFileError when it exists but is not a valid calibration (naming file, line and
// key): a damaged calibration must be looked at, not silently replaced by the nameplate.
// `written_by`, if given, receives the axis that wrote the file (calibration_file.hpp).
struct StoredAxis;
StoredCalibration load_stored_calibration(ControllerConfig& config, StoredAxis* written_by = nullptr);
[[nodiscard]] std::string_view to_string(StoredCalibration s);

// The schema of every controller key (docs/configuration.md is generated from it).
[[nodiscard]] const ConfigSchema<ControllerConfig>& controller_schema();

// The top-level sections the controller schema owns.
[[nodiscard]] const std::vector<std::string>& controller_sections();

// Fills the fields that follow from others (the motor-relative defaults, then every
// component's copy of the motor model through core::DriveConfig::derive_from_motor()) and
// checks rules that involve several keys. Throws ConfigError naming both keys, with the file
// and line of those `table` gives (`key_prefix` as in parse_controller_config()).
void finalize(ControllerConfig& config, std::string_view source, const toml::table* table = nullptr,
              std::string_view key_prefix = {});

// Parses the controller sections of `table`; sections in `foreign` belong to someone else.
[[nodiscard]] ControllerConfig parse_controller_config(const toml::table& table, std::string_view source,
                                                       const std::vector<std::string>& foreign,
                                                       std::string_view key_prefix = {});

[[nodiscard]] ControllerConfig default_controller_config();

// Why a calibration was refused as rs_outside_window (core::CalibrationFailure::kRsOutsideWindow),
// for a person: the resistance its events measured (`measured_ohm`, their scatter), the
// plausibility window and the nameplate that set it, and what to check: about half the nameplate
// is a line-to-line (terminal) value entered as the phase's, about a thousandth or a thousand
// times a unit. For the daemon's log and simulate's report (it allocates).
[[nodiscard]] std::string rs_outside_window_text(const core::DriveConfig& d, double measured_ohm, double scatter_ohm);

// What a winding_warm refusal measured against, for the daemon's log and simulate's report.
inline constexpr std::string_view kWindingWarmMeasure =
    "the thermal filter's, or the measured Rs0 read through the calibration in use; "
    "calibration.max_winding_rise_C; on the nameplate's Rs0 the thermal model's rise and the filter's rise beyond it, "
    "taken beyond that limit only while T0's uncertainty (calibration.model_rise_std_fraction of the model's rise, half "
    "the filter's excess: the nameplate's error or warmth) stays below half the nameplate's";

// What to do about a calibration that timed out (too few events by calibration.timeout_s: the
// daemon's log, simulate's warning). For injection, a steady unloaded run lets the pairs pass
// their guards. The no-injection baseline sees Rs only through Rs iq in the motoring voltage
// (about 1 % of it on Table I's machine), so calibrating unloaded would take away the little it
// sees; the thermal model alone measures nothing.
[[nodiscard]] inline std::string_view calibration_timeout_advice(core::EstimatorKind kind) {
  switch (kind) {
    case core::EstimatorKind::kNoInjection:
      return "estimator.kind = \"no-injection\" sees Rs only through Rs iq in the motoring voltage, a per cent or so "
             "of it: calibrate with estimator.kind = \"injection\", or enter calibration.rs0_ohm and calibration.t0_C "
             "measured at a known temperature (a four-wire reading of the cold winding)";
    case core::EstimatorKind::kNone:
      return "estimator.kind = \"none\" measures no resistance: calibrate with estimator.kind = \"injection\", or "
             "enter calibration.rs0_ohm and calibration.t0_C measured at a known temperature";
    case core::EstimatorKind::kInjection:
      break;
  }
  return "calibrate unloaded at a steady speed";
}

// What to do about a calibration refused as uncertain (the daemon's log, simulate's report): a
// whole run could not learn the bridge's voltage (Vx is learned only unloaded and slow), one cut
// short at its timeout had too few events, and its pairs say what stopped the rest; without
// injection, calibration_timeout_advice's.
[[nodiscard]] inline std::string_view uncertain_calibration_advice(bool cut_short, core::EstimatorKind kind) {
  if (kind != core::EstimatorKind::kInjection || cut_short) {
    return calibration_timeout_advice(kind);
  }
  return "the bridge's voltage was not learned: calibrate unloaded (|iq| below "
         "injection.vx_learning_max_iq_fraction of the event's smallest pulse), below "
         "injection.vx_learning_max_speed_rad_s";
}

// For a completed calibration's report: "" when its Rs0 averaged the `wanted` events
// (calibration.events), else " on N of M events, at its timeout (calibration.min_events)".
[[nodiscard]] std::string calibration_events_text(int used, int wanted);
// The same followed by "; its pairs: ..." (why it fell short), or "" for a whole calibration.
[[nodiscard]] std::string cut_short_calibration_text(int used, int wanted, const core::OutcomeCounts& pairs,
                                                     const core::AbortCounts& aborts,
                                                     core::EstimatorKind kind = core::EstimatorKind::kInjection);
// "; its pairs: ..." (a calibration's pairs by outcome: why it fell short), or "" without injection:
// the no-injection baseline and the thermal model alone make no pairs, and "its pairs: no pair"
// read as if something had stopped them.
[[nodiscard]] std::string calibration_pairs_text(core::EstimatorKind kind, const core::OutcomeCounts& pairs,
                                                 const core::AbortCounts& aborts);

// For a completed calibration's report: "" when T0 is the ambient's or an operator's reading,
// else " (+- S K: the ambient plus the thermal model's rise)" (core::Calibration::t0_rise_std_C).
[[nodiscard]] std::string t0_rise_text(const core::Calibration& c);

// A configuration that loads but is measured to mislead: defaults that describe the reference
// machine (Table I, 11.9 kW) and no other, on a motor that is another (continuous current
// under half or over twice the reference's), as the thermal model left at the reference's
// values; a rated speed the EMF does not let the drive reach; a speed loop that amplifies the
// encoder's rounding; a derating floor above the motor's rated peak current; an injection
// method other than fixed-magnitude bipolar on a machine configured as salient, or one without
// its flux map.
// Warnings, not errors: the drive runs, but its model, derating or estimates are not what
// the engineer meant. pmsm-thermald logs them at start and under --check; simulate prints them.
[[nodiscard]] std::vector<std::string> configuration_warnings(const ControllerConfig& config);

// Why an injection method other than fixed-magnitude bipolar misleads on a machine configured
// as salient (injection.max_torque_disturbance_Nm above 0), or "" (a round rotor, no injection,
// or that method). configuration_warnings gives it for the configured method; the daemon logs
// it with the first INJECTION_REPORT of another method (an INJECTION_COMMAND picked it).
[[nodiscard]] std::string salient_method_warning(const core::DriveConfig& d, core::InjectionMethod method,
                                                 core::Separation separation);

// What a relative error of the incremental Lq reads as in a torque-neutral pair's Rs, at the
// rated current and this (mechanical) speed with the commissioned values:
// w_e Lq iq |Lq - Ld| / (psi Rs) (3.7 on the robustness suite's 30 mohm IPM at 314 rad/s).
[[nodiscard]] double incremental_lq_sensitivity(const core::DriveConfig& d, double speed_rad_s);
// The speed the warning below takes it at: the rated speed, or the speed where the rated current
// on the q axis takes the whole voltage (control.nominal_dc_bus_V), w_e sqrt(psi^2 + (Lq iq)^2),
// if that is lower.
[[nodiscard]] double incremental_lq_sensitivity_speed_rad_s(const ControllerConfig& config);
// From this sensitivity on, a salient machine without its flux map is warned about.
inline constexpr double kIncrementalLqSensitivityWarning = 0.1;
// Why a salient machine (a torque budget) with torque-neutral fixed-magnitude pulses and no flux
// map (motor.lq_map_H, motor.lq_rated_H) reads off under load (high motoring, low generating),
// with the sensitivity above, or "" (a round rotor, a map, another method, or a sensitivity below
// kIncrementalLqSensitivityWarning).
[[nodiscard]] std::string salient_flux_map_warning(const ControllerConfig& config);

// Why a drive measures rarely, when at least kPairRejectionAdviceMinPairs pairs were judged
// (core::pair_judged: recorded to their end) and at least half of them
// were rejected as speed or load changes between their two recordings; "" otherwise. Two
// causes: a duty cycle with few steady spells, or (named only without a torque budget,
// injection.max_torque_disturbance_Nm = 0) a salient rotor whose pulses' reluctance torque the
// speed loop answers. simulate prints it at the end of a run; pmsm-thermald logs it once, from
// its INJECTION_REPORTs.
inline constexpr std::uint32_t kPairRejectionAdviceMinPairs = 20;
[[nodiscard]] std::string pair_rejection_advice(const core::OutcomeCounts& pairs, const core::DriveConfig& d);

// The rated torque the speed loop's noise is judged against: Kt (dq) x the rated peak current.
[[nodiscard]] double speed_loop_rated_torque_Nm(const core::DriveConfig& d);
// The speed-loop bandwidth at which the encoder's rounding makes kSpeedLoopQuantisationTorqueShare
// of speed_loop_rated_torque_Nm() of torque demand (RMS), with the configured motor inertia,
// encoder, PLL and period.
[[nodiscard]] double quantisation_limited_speed_bandwidth_rad_s(const core::DriveConfig& d);

}  // namespace pmsm::app
