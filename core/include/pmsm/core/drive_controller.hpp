// The drive controller: one control period from sensor readings to duty cycles, with the
// injection scheduler, the resistance estimator and the thermal observer running inside it.
//
// Pure and deterministic: physical inputs in, duties and a fixed-size telemetry record out;
// no clock (the period is counted), no I/O, no allocation after construction. The daemon and
// the in-process simulator both drive it the same way:
//
//   sample k -> step() -> command applied by the power stage in period k+1
//
// so the voltage applied during period k is the command computed at step k-2 from the
// controller's point of view at step k; the estimator pairs it with the currents measured at
// the two ends of that period (docs/estimator.md).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <utility>

#include "pmsm/core/angle_check.hpp"
#include "pmsm/core/angle_tracker.hpp"
#include "pmsm/core/baseline_estimator.hpp"
#include "pmsm/core/current_controller.hpp"
#include "pmsm/core/field_weakening.hpp"
#include "pmsm/core/injection_scheduler.hpp"
#include "pmsm/core/inverter_sweep.hpp"
#include "pmsm/core/machine_equations.hpp"
#include "pmsm/core/modulation.hpp"
#include "pmsm/core/motor_params.hpp"
#include "pmsm/core/speed_controller.hpp"
#include "pmsm/core/thermal_observer.hpp"

namespace pmsm::core {

enum class EstimatorKind : std::uint8_t {
  kInjection,      // the scheduler's method (fixed-magnitude / fixed-angle / DC)
  kNoInjection,    // the baseline of baseline_estimator.hpp
  kNone,           // thermal model only
};

struct DriveConfig {
  double period_s = 1e-4;
  MotorParams motor{};               // the controller's (commissioned) motor parameters
  AngleTrackerConfig angle{};
  CurrentControllerConfig current{};
  SpeedControllerConfig speed{};
  int speed_decimation = 10;         // speed loop every N current-loop periods
  // Above the id = 0 speed, a negative d current that holds the current loop's command at a
  // share of its voltage limit (field_weakening.hpp); held while an injection pair runs.
  FieldWeakeningConfig field_weakening{};
  // The shaft's speed limit (mechanical, either direction; 0: none). Speed mode clamps its
  // set-point to it; torque mode bounds the torque by a proportional speed loop around it,
  // G (limit - speed) forwards and G (-limit - speed) backwards (ODrive's torque-mode velocity
  // limit), so that an unloaded shaft settles at the limit instead of running on to the
  // supervisor's OVERSPEED; under a load T it settles at limit - T / G. G = J wfb with
  // wfb = min(5 x the speed loop's bandwidth, half the PLL's): the speed loop's own Kp (J x
  // 60 rad/s) left the Table I motor 31.7 Nm at its rated speed, below its rated torque, and
  // wfb stays where the PLL's speed lags little (docs/daemon.md, "Faults and limits").
  double speed_limit_rad_s = 0.0;
  // The speed set-point's ramp (mechanical rad/s^2, 0: none). Speed mode moves its reference
  // towards the set-point at most this fast and adds the torque J x the ramp's slope (the
  // commissioned inertia) as a feed-forward, so that the speed loop's integral does not carry
  // the accelerating torque. Without it a set-point step leaves that torque in the integral at
  // the step's end, which overshoots the set-point by several per cent of the step (and a
  // step to the speed limit overshoots the limit).
  double speed_ramp_rad_s2 = 0.0;
  DeadTimeCompensation dead_time{0.9e-6, 0.0, 1.0};
  // The bus the estimator's bridge error Vx is referred to (0: none). The bridge loses its dead
  // time's share of the bus, dead_time / period x Vdc, plus the devices' drop: on a bus that
  // moves, a Vx learned at one voltage is wrong at another (the reference plant's bridge, 1 us
  // and 1 V at 10 kHz, loses 7.5 V at 650 V and 6.5 V at 552.5 V). Each period's voltage reaches
  // the estimator with dead_time / period x (Vdc - this) x its sign pattern taken out, so that
  // Vx, its prior and the one stored with the calibration are the error at this bus whatever
  // the bus does (docs/estimator.md section 4). The loader sets control.nominal_dc_bus_V.
  double vx_reference_bus_V = 0.0;
  InjectionConfig injection{};
  // The calibration procedure, whatever the run-time method: fixed-magnitude bipolar at two
  // levels, the one procedure that separates Rs0 from the inverter's voltage error without
  // depending on the zero-current region (docs/estimator.md). Filled from `injection` by
  // the configuration loader.
  InjectionConfig calibration_injection{};
  EstimatorKind estimator = EstimatorKind::kInjection;
  BaselineConfig baseline{};
  double baseline_publish_s = 1.0;   // how often the no-injection estimate is fused
  ThermalModelConfig thermal{};
  Calibration calibration{.rs0_std_fraction = kNameplateRs0StdFraction};
  DeratingConfig derating{};
  double thermal_update_s = 0.01;    // thermal model / filter period
  double magnet_coefficient_per_C = -0.0012;  // NdFeB remanence (flux) temperature coefficient
  // The magnet estimate is valid this long (thermal time) after its last EMF measurement: at
  // standstill (time-based recordings) nothing measures it, and a value kept from an hour ago
  // must not read as today's.
  double magnet_max_age_s = 300.0;
  // The magnet estimate is a scalar Kalman filter on the events' EMF readings: between them
  // its variance grows by this squared per second of thermal time (a random walk). A walk
  // covers a steady warming of rate r over a gap dt when q >= r sqrt(dt): the reference's
  // magnets warm by up to 0.5 C/s of thermal time, and events at low speed come every 2-4 s,
  // so 1 C/sqrt(s). (0.5 left the 48 V servo's band holding the truth 84 % of the time; docs/estimator.md.)
  double magnet_drift_C_per_sqrt_s = 1.0;
  // A calibration run that measured no Ke0 (at rest, or slower than
  // injection.min_speed_for_angle_rad_s) takes one from the first turning events while the
  // drive knows the magnets' temperature better than this standard uncertainty (C): the rotor
  // between the ambient and the housing's estimate (offer_magnet_reference; docs/estimator.md
  // section 8, "A magnet reference after a calibration at rest"). 0: never; the magnets then go
  // unmeasured.
  double magnet_reference_max_std_C = 5.0;
  // The bridge's voltage error measured before the calibration's events (inverter_sweep.hpp):
  // its zero-current band replaces dead_time.current_band_A.
  InverterSweepConfig inverter_sweep{};
  // The rotor angle's offset checked before the sweep (angle_check.hpp): its correction is
  // applied to the controller's angle and kept with the calibration.
  AngleCheckConfig angle_check{};
  int calibration_events = 6;        // events averaged into Rs0 / Ke0 (about 2.5 s at no load)
  // A calibration whose Rs0 is less certain than this (its standard error over Rs0) is
  // refused and the calibration in use stays: every later temperature would carry the error
  // (2 % of Rs0 is about 5 C at 25 C; calibrations that learn the bridge's voltage have
  // 0.2-0.8 %, docs/estimator.md section 6). It happens where the events cannot learn it
  // (turning faster than injection.vx_learning_max_speed_rad_s, or pairs that do not reverse
  // the current), so Rs0 rests on the inverter-voltage prior.
  double calibration_max_rs0_std_fraction = 0.02;
  double calibration_timeout_s = 20.0;  // give up (keep the stored calibration) after this
  // A calibration that has published at least this many events by its timeout completes with
  // them (their inverse-variance Rs0, refused as a whole one would be) instead of giving up;
  // 0, or calibration_events or more: it gives up.
  int calibration_min_events = 3;
  // A calibration refers Rs0 to the temperature it is given. From the ambient sensor that is the
  // winding's only on a machine at rest long enough: one the thermal filter holds warmer than
  // that by more than this (the drive's own losses since it started, a stored warm state) is
  // refused, and the calibration in use stays. 0: no check.
  double calibration_max_winding_rise_C = 5.0;
  // On the nameplate's Rs0 (no calibration yet) a calibration on the ambient sensor refers Rs0 to
  // the ambient plus the thermal model's rise by the drive's own losses, which is known to this
  // fraction of itself (the commissioned winding capacity and copper loss, 10-20 % each): T0's
  // uncertainty (Calibration::t0_rise_std_C), in the band. Above calibration_max_winding_rise_C
  // such a calibration is taken while that uncertainty stays below half the nameplate's own
  // (Calibration::rs0_std_fraction, in kelvin), and refused beyond (docs/estimator.md section 6).
  double calibration_model_rise_std_fraction = 0.25;
  std::size_t recording_capacity = 8192;      // periods per recording (preallocated)

  // Fills every sub-configuration's copy of the motor model and of the period from `motor`
  // and `period_s`: the current controller's Rs, Ld, Lq and flux linkage, the speed loop's
  // inertia and period, the angle tracker's pole pairs, the injection's and the calibration
  // injection's motor model, the baseline's. DriveController applies it to its own copy, so
  // no sub-configuration can disagree with `motor`. Allocation-free.
  void derive_from_motor();
};

// A copy of `config` with derive_from_motor() applied.
[[nodiscard]] DriveConfig with_motor_derived(DriveConfig config);

// The resistance the drive sees at the nameplate's temperature (motor.rs_reference_temp_C): the
// winding's nameplate value and a motor cable's (ThermalModelConfig::cable_resistance_20C_ohm)
// at that temperature. What the current loop, the pulse budget and an uncalibrated Rs0 take.
[[nodiscard]] inline double terminal_resistance_ohm(const DriveConfig& config) {
  return config.motor.rs_ohm +
         cable_resistance_at_C(config.thermal.cable_resistance_20C_ohm, config.motor.rs_reference_temp_C);
}

enum class DriveMode : std::uint8_t { kDisabled, kTorque, kSpeed };

struct DriveCommand {
  DriveMode mode = DriveMode::kDisabled;
  double speed_ref_rad_s = 0.0;     // mechanical
  double torque_ref_Nm = 0.0;
  double ambient_C = 25.0;          // from the drive's ambient / coolant sensor
  bool request_injection = false;   // start an injection event now
};

struct DriveInput {
  Abc i_A{};                        // phase currents (scaled by the controller's own calibration)
  std::uint32_t encoder_count = 0;
  double vdc_V = 0.0;
  bool valid = true;                // false: no fresh sample this period
  // Control periods this step stands for, so that the drive's clocks (the thermal model, the
  // calibration's timeout, the magnets' age) keep real time: without a sample (a lost sample's
  // timeout) the periods that timeout took; with one, 1, or more when the samples before it
  // were lost on the bus (its sequence says how many): the angle tracker then predicts over
  // them, no period sample is built across them and the injection event in progress is lost.
  std::uint32_t periods = 1;
  // Whether this sample follows the one the controller last used by `periods` (the power
  // stage's sequence numbers, DriveNode): the shaft turned by that many periods since. False
  // otherwise: after unusable steps the angle tracker then starts afresh.
  bool continuous = true;
};

// Whether a sample can be controlled on at all: finite currents and a finite, positive DC
// bus (the modulator divides by it). The supervisor's windows are narrower; this is the
// controller's own last line, so that NaN never reaches a duty cycle.
[[nodiscard]] bool controllable(const DriveInput& in) noexcept;

struct DriveOutput {
  std::array<double, 3> duty{0.5, 0.5, 0.5};
  bool enable = false;
  // The controller could not compute a finite, in-range command from this period's input
  // (enable is then false). The drive node turns it into a latched kInternal fault.
  bool fault = false;
};

// Counters of pair outcomes, indexed by PairOutcome.
using OutcomeCounts = std::array<std::uint32_t, static_cast<std::size_t>(PairOutcome::kCount)>;
// Counters of aborted pairs by cause, indexed by AbortCause.
using AbortCounts = std::array<std::uint32_t, static_cast<std::size_t>(AbortCause::kCount)>;

// Why the last calibration run failed.
enum class CalibrationFailure : std::uint8_t {
  kNone = 0,
  kTimeout = 1,    // not enough published events within calibration_timeout_s
  kUncertain = 2,  // Rs0's standard error above calibration_max_rs0_std_fraction
  kAngleOffset = 3,  // the angle check found the rotor angle further off than it corrects
  kWindingWarm = 4,  // the filter holds the winding above the ambient it would be referred to
  // An operator's temperature far outside what the drive measured of the winding moments ago
  // (more than 4 sigma + calibration_max_winding_rise_C from the filter's winding)
  kTemperatureImplausible = 5,
  // The ambient / coolant sensor the calibration would be referred to stopped reporting: its
  // last reading is held, of unknown age (DriveNode::ambient_held)
  kAmbientHeld = 6,
  // The Rs0 measured is not above the motor cable's resistance at T0
  // (ThermalModelConfig::cable_resistance_20C_ohm): Eq. 1 would have no winding left
  kCableTakesAll = 7,
  // The calibration's events measured, one after another, a resistance on the same side
  // outside the plausibility window that the nameplate sets (InjectionConfig::rs_min_ohm,
  // rs_max_ohm): the nameplate and the winding disagree (a line-to-line value entered as the
  // phase's, a wrong unit). kCalibrationOutsideWindowEvents of them end the calibration.
  kRsOutsideWindow = 8,
  // Asked for while OVERTEMPERATURE was latched (DriveNode): a calibration starts the thermal
  // filter again from the temperature it is given, which would let the trip clear on the next
  // stop with the winding still hot.
  kOvertemperatureLatched = 9,
};
// Calibration events in a row, all below or all above the plausibility window, that refuse the
// calibration as kRsOutsideWindow.
inline constexpr int kCalibrationOutsideWindowEvents = 3;
[[nodiscard]] const char* calibration_failure_name(CalibrationFailure f);
// Refused as it was asked for, before any of it ran.
[[nodiscard]] constexpr bool refused_on_request(CalibrationFailure f) {
  return f == CalibrationFailure::kWindingWarm || f == CalibrationFailure::kTemperatureImplausible ||
         f == CalibrationFailure::kAmbientHeld || f == CalibrationFailure::kOvertemperatureLatched;
}
// A refusal of a resistance the calibration measured (DriveTelemetry::calibration_rs0_ohm and its
// standard error, or for kRsOutsideWindow its events' mean and scatter).
[[nodiscard]] constexpr bool refused_measured_rs0(CalibrationFailure f) {
  return f == CalibrationFailure::kUncertain || f == CalibrationFailure::kCableTakesAll ||
         f == CalibrationFailure::kRsOutsideWindow;
}
// A refusal that measured the winding against the temperature asked for (calibration_winding_rise_C).
[[nodiscard]] constexpr bool refused_on_winding_rise(CalibrationFailure f) {
  return f == CalibrationFailure::kWindingWarm || f == CalibrationFailure::kTemperatureImplausible;
}
// Pairs by outcome (a calibration's, an event's), most frequent first, e.g. "34
// rejected_load_change, 4 accepted"; "no pair" when there were none. With the aborted pairs'
// causes (`aborts`; its kNone count is not shown), "16 aborted (12 motoring_needs_voltage, 4
// current_limit), 8 accepted". Not for the control period (it allocates).
[[nodiscard]] std::string pair_outcomes_text(const OutcomeCounts& counts, const AbortCounts& aborts = {});

// How the last calibration run ended (published on the bus: THERMAL_ESTIMATE.CalibrationResult).
enum class CalibrationOutcome : std::uint8_t {
  kNone = 0,       // none has ended since start, or one is running (or suspended by a fault)
  kDone = 1,       // completed: its Rs0 is in use (the daemon stores it when it has a file)
  kAborted = 2,    // stopped by a command (a fault or disabling the drive only suspends it)
  kTimedOut = 3,   // CalibrationFailure::kTimeout
  kRefused = 4,    // CalibrationFailure::kUncertain, kAngleOffset, kCableTakesAll, kRsOutsideWindow, or refused on request
};

// An EMF (magnet) reading is refused outside kMagnetPlausibleMin_C..kMagnetPlausibleMax_C
// (what any NdFeB grade survives, any ambient reaches) or further than kMagnetGateSigma from
// the estimate (its band, the reading's error bar and both systematic parts together).
inline constexpr double kMagnetPlausibleMin_C = -60.0;
inline constexpr double kMagnetPlausibleMax_C = 300.0;
inline constexpr double kMagnetGateSigma = 6.0;

// Why the last EMF (magnet) reading was refused (DriveController::update_magnet).
enum class MagnetRefusal : std::uint8_t {
  kNone = 0,
  kNotANumber = 1,     // the reading or its error bar is not finite
  kImplausible = 2,    // outside what any NdFeB grade survives or any ambient reaches
  kInconsistent = 3,   // further than kMagnetGateSigma from the estimate's band
};
// What the reason means, for a log line.
[[nodiscard]] const char* magnet_refusal_text(MagnetRefusal r);

// The last refused EMF reading: why, the temperature it read (NaN when none) and the estimate
// (and sigma, the reading's included) it was refused against (valid only for kInconsistent).
struct MagnetRefusalReport {
  MagnetRefusal reason = MagnetRefusal::kNone;
  double reading_C = 0.0;
  double against_C = 0.0;
  double against_std_C = 0.0;
};

struct DriveTelemetry {
  std::uint64_t period = 0;
  double time_s = 0.0;
  double theta_e_rad = 0.0;
  double speed_m_rad_s = 0.0;
  Dq i_A{};
  Dq i_ref_A{};
  Dq injection_A{};                 // the injection's part of i_ref
  Dq v_V{};
  bool voltage_limited = false;
  // The q-axis current the speed loop or the torque command asked for this period and the
  // (derated) limit it was clamped to (0 and infinity while disabled), and whether the speed
  // limit bound tighter than the current limit (speed mode: the set-point clamped; torque
  // mode: the torque folded back below what the current limit allows).
  double motoring_iq_wanted_A = 0.0;
  double motoring_iq_limit_A = std::numeric_limits<double>::infinity();
  bool speed_limited = false;
  // The current limit cut the motoring reference, or is zero (fully derated) while enabled.
  // (The speed loop's own clamp at the limit gives the limit back within rounding.)
  [[nodiscard]] bool current_limited() const {
    return motoring_iq_limit_A <= 0.0 ||
           (motoring_iq_wanted_A != 0.0 && std::abs(motoring_iq_wanted_A) >= motoring_iq_limit_A * (1.0 - 1e-9));
  }
  SchedulerPhase injection_phase = SchedulerPhase::kIdle;
  bool injection_active = false;
  ThermalEstimate thermal{};
  bool thermal_valid = false;       // thermal holds a model/filter output (not before the first update)
  double current_limit_A = 0.0;    // the tighter of the winding's and the magnets' derating
  bool derating = false;           // the winding's estimate derates the current limit
  bool magnet_derating = false;    // the magnets' estimate derates it (DeratingConfig::magnet_*)
  bool time_to_limit_valid = false;
  double time_to_limit_s = 0.0;
  bool magnet_valid = false;
  double magnet_C = 0.0;
  double magnet_std_C = 0.0;         // its standard error, Ke0's included (at each thermal update)
  double magnet_upper_C = 0.0;       // what the magnets derate on (DriveController::update_magnet)
  std::uint32_t magnet_rejected = 0;  // EMF measurements refused as implausible
  MagnetRefusalReport magnet_last_refusal{};  // the last refused one
  // The magnet reference taken from turning events (magnet_reference_completed()): the rotor's
  // temperature the events' Ke was referred from to T0, its standard uncertainty, and how many
  // events; 0 until one was taken.
  double magnet_reference_at_C = 0.0;
  double magnet_reference_std_C = 0.0;
  int magnet_reference_events = 0;
  OutcomeCounts outcomes{};
  // The pairs of the calibration run in progress, or of the last one that ended, by outcome: why
  // a calibration timed out (pair_outcomes_text).
  OutcomeCounts calibration_outcomes{};
  // Its pairs by abort cause (kNone: the pairs not aborted; counted so, without a test, since the
  // test cost the control step 15 instructions through the inliner's choices).
  AbortCounts calibration_aborts{};
  std::uint32_t estimates_published = 0;
  std::uint32_t estimates_gated = 0;  // implausible against the thermal filter's prediction
  // Held estimates (dated after their publication) dropped because the filter restarted before
  // their time: a calibration (which sets the winding's temperature) or a restored state.
  std::uint32_t estimates_dropped_at_restart = 0;
  std::uint32_t events_without_estimate = 0;
  double vx_V = 0.0;                  // the inverter voltage estimate
  double vx_std_V = 0.0;
  double vx_bus_slope = 0.0;          // what the compensation's dead-time share of the bus misses (V/V)
  double vx_bus_slope_std = 0.0;
  double lq_H = 0.0;                  // the q-axis inductance the estimator has learned
  double lq_std_H = 0.0;
  double lq_saturation_H = 0.0;       // its saturation: secant Lq lost where s = 1 (core::LqShape)
  double lq_bend_H = 0.0;             // and its bend: a further lq_bend_H s^2 lost
  std::uint32_t lq_listening_pairs = 0;    // pairs with no pulse under a load the torque budget refuses
  std::uint32_t lq_listening_learned = 0;  // those that taught the curve
  double lq_emf_d_Wb = 0.0;           // the angle error's EMF share psi delta learned with it
  double lq_emf_d_std_Wb = 0.0;
  bool lq_saturation_resolved = false;       // by pairs at two loads (else the commissioned gap holds)
  bool calibrating = false;
  bool inverter_sweep_active = false;  // the calibration's bridge sweep is running
  bool angle_check_active = false;     // the calibration's rotor-angle check is running
  double angle_correction_rad = 0.0;   // added to the commissioned rotor-angle offset
  double dead_time_band_A = 0.0;       // the band the estimator's pattern uses
  bool calibrated = false;
  bool calibration_failed = false;  // the last calibration run failed (calibration_failure says why)
  CalibrationFailure calibration_failure = CalibrationFailure::kNone;
  CalibrationOutcome calibration_outcome = CalibrationOutcome::kNone;
  // The last completed or refused calibration's Rs0 and its standard error (the events'
  // inverse-variance combination, referred to T0); 0 before any, from the start of a
  // calibration run, and after one that timed out. After kRsOutsideWindow: the mean of the
  // resistances its events measured outside the window (as measured, not referred to T0) and
  // their scatter (sample standard deviation).
  double calibration_rs0_ohm = 0.0;
  double calibration_rs0_std_ohm = 0.0;
  // The events that Rs0 averaged: calibration_events, or fewer for one that completed at its
  // timeout (DriveConfig::calibration_min_events); 0 alongside calibration_rs0_ohm's 0.
  int calibration_events = 0;
  // A calibration refused as kWindingWarm or kTemperatureImplausible: how far above the
  // temperature it would be referred to (the ambient, the operator's) the filter held the winding,
  // or, at a calibration's end, the measured Rs0 read through the calibration in use put it.
  double calibration_winding_rise_C = 0.0;
};

// One published resistance estimate, from an event's accepted pairs (rejected pairs are
// reported, never published as estimates).
struct ResistanceEstimate {
  double time_s = 0.0;              // published
  double measured_at_s = 0.0;       // the time it belongs to (EventEstimate::measured_at_s)
  double rs_ohm = 0.0;
  double rs_std_ohm = 0.0;
  double winding_C = 0.0;           // Eq. 1 through the calibration
  double vx_V = 0.0;                // the inverter voltage the estimate is conditioned on
  double vx_std_V = 0.0;
  double lq_H = 0.0;                // the q-axis inductance the fits used
  int pairs = 0;
  bool fused = false;               // the thermal filter took it (not gated out)
  bool vx_learning = false;         // this event also refined the inverter voltage
  // The spread of its recordings' mean buses, and whether that alone kept it from refining the
  // inverter voltage (EventEstimate::bus_spread_V; diagnostics).
  double bus_spread_V = 0.0;
  bool vx_refused_bus_spread = false;
  double joint_rs_ohm = 0.0;        // the event's joint fit before fusion (diagnostics)
  double joint_vx_V = 0.0;
};

// A commissioning step of the calibration (the rotor-angle check, the bridge sweep) that a stop,
// a lost sample or a moving operating point cut short starts again once the drive has run
// `holdoff_s` without a stop, at most `max_attempts` starts per calibration.
struct CalibrationStepRestart {
  bool pending = false;
  int attempts = 0;
  double running_s = 0.0;  // the drive's run time since the step became pending

  void reset() { *this = {}; }
  // The step ended: pending again when `retry` and attempts remain.
  void ended(bool retry, int max_attempts) {
    pending = retry && attempts < max_attempts;
    running_s = 0.0;
  }
  // One period while pending: true when the step is to start now (counted as an attempt).
  bool due(bool enabled, double period_s, double holdoff_s) {
    running_s = enabled ? running_s + period_s : 0.0;
    if (running_s < holdoff_s) {
      return false;
    }
    pending = false;
    ++attempts;
    return true;
  }
};

class DriveController {
 public:
  explicit DriveController(const DriveConfig& config);

  // One control period.
  const DriveOutput& step(const DriveInput& in, const DriveCommand& command);

  // Starts an Rs0 calibration at a known winding temperature: the next calibration_pairs
  // accepted pairs are averaged into Rs0 (and Ke0), and the thermal filter restarts there.
  // `from_ambient_sensor`: the temperature is the ambient / coolant sensor's (not an operator's
  // reading of the winding): refused with kWindingWarm while the filter holds the winding more
  // than calibration_max_winding_rise_C above it. An operator's reading is refused with
  // kTemperatureImplausible when the filter measured the winding within
  // kRecentMeasurement_s and the reading lies more than 4 sigma + calibration_max_winding_rise_C
  // from it. `ambient_held`: the ambient sensor's temperature is its last reading, held since it
  // stopped reporting: a calibration on it is refused with kAmbientHeld.
  void start_calibration(double known_temp_C, bool from_ambient_sensor = false, bool ambient_held = false);
  // A calibration asked for while OVERTEMPERATURE is latched: refused as it was asked for
  // (kOvertemperatureLatched); the thermal filter and the calibration in use stay. A calibration
  // already running (suspended by the fault) goes on once the fault is cleared, as before.
  void refuse_calibration_while_overtemperature();
  // Stops a calibration in progress and keeps the calibration in use (nothing is stored).
  void abort_calibration();

  // The operator's injection settings (the protocol's INJECTION_COMMAND): method and
  // separation, amplitude F (<= 0: keep the configured one) and the interval between events
  // (<= 0: only on request). An event in progress is abandoned when the settings change;
  // during a calibration they take effect once it ends. Returns whether anything changed.
  bool configure_injection(InjectionMethod method, Separation separation, double f_A, double interval_s);

  // Injection events, for the simulator, which forks its twin without injection from a copy of
  // the drive taken between events (InjectionScheduler::between_events, hold_events): whether
  // none is in progress; when the next scheduled one is due (drive time; an operator's or a
  // calibration's request may start one sooner); and from here on none starts.
  [[nodiscard]] bool between_injection_events() const { return scheduler_.between_events(); }
  [[nodiscard]] double next_injection_event_s() const { return scheduler_.next_event_s(); }
  void hold_injection_events() { scheduler_.hold_events(); }

  // Thermal time scale of the controller's model (the test acceleration; 1 on a machine).
  // The magnet estimate's age keeps the thermal time it had (magnet_age_now_s() scales the time
  // since the last thermal update by the scale in force).
  void set_thermal_time_scale(double time_scale) {
    magnet_age_s_ += thermal_elapsed_s_ * (observer_.time_scale() - time_scale);
    observer_.set_time_scale(time_scale);
  }
  [[nodiscard]] double thermal_time_scale() const { return observer_.time_scale(); }
  // The standard deviation of one current sample's noise (A; the drive measures it with the
  // ADC offsets at power-up): the sign pattern built from measured currents is corrected for
  // it (mean_soft_sign_of_measured). 0, not finite or negative: no correction.
  void set_current_noise_A(double sigma_A);
  [[nodiscard]] double pattern_noise_A() const { return pattern_noise_A_; }
  // The thermal filter's state kept from before a restart, `downtime_s` (controller seconds)
  // old: cooled through the downtime by the model. Without it (or a calibration run) the
  // filter starts from the ambient sensor with a wide uncertainty and takes its first
  // measurement ungated, never from the calibration's T0 as if the motor were soaked there.
  void restore_thermal_state(const ThermalState& state, double downtime_s, double ambient_C);
  // The restart's own ambient, read before the first thermal update after a restore: a move
  // from the stored ambient widens the restored state towards it
  // (ThermalObserver::refer_restored_to_ambient). Returns the winding's shift; 0 when there is
  // nothing to refer (no restore pending, the same ambient, the filter already ran).
  double refer_restored_state_to_ambient(double ambient_C) { return observer_.refer_restored_to_ambient(ambient_C); }
  [[nodiscard]] ThermalState thermal_state() const { return observer_.state(); }
  // The error of the estimator's bus slope (vx_bus_slope) the winding's filter has learned from
  // the estimates under load (V/V, ThermalObserver's BusSlopeTerm) and its standard deviation:
  // 0 and 0 until an estimate held Vx; near 0 with the slope's prior while the bus stays where Vx
  // was learned.
  [[nodiscard]] double bus_slope_error() const { return observer_.bus_slope_error(); }
  [[nodiscard]] double bus_slope_error_std() const { return observer_.bus_slope_error_std(); }
  // Estimates dated after their publication, waiting for their time (hold_estimate()).
  [[nodiscard]] std::size_t held_estimates() const noexcept { return held_count_; }

  [[nodiscard]] const DriveTelemetry& telemetry() const { return telemetry_; }
  // The magnets' flux linkage as the drive knows it now: the calibration's Ke0 / p at its T0
  // (else the commissioned flux at motor.rs_reference_temp_C), at the magnets' temperature (their
  // valid estimate, else the thermal filter's housing: the rotor follows the housing), falling by
  // the magnet coefficient per kelvin. Computed when asked (the published torque), not every period.
  [[nodiscard]] double present_flux_linkage_Wb() const noexcept;
  // The torque of a q current and an id iq product (means over an interval, or one sample's):
  // Eq. 10 with the reluctance torque (the commissioned Ld and Lq) at the present flux linkage.
  // Without arguments, the last sample's.
  [[nodiscard]] double torque_estimate_Nm(double iq_A, double id_iq_A2) const noexcept {
    return 1.5 * config_.motor.pole_pairs *
           (present_flux_linkage_Wb() * iq_A + (config_.current.ld_H - config_.current.lq_H) * id_iq_A2);
  }
  [[nodiscard]] double torque_estimate_Nm() const noexcept {
    return torque_estimate_Nm(telemetry_.i_A.q, telemetry_.i_A.d * telemetry_.i_A.q);
  }
  // The tracker follows the shaft: telemetry().speed_m_rad_s and torque_estimate_Nm() are this
  // step's. False from the first step without a usable sample (a lost sample, a latched fault)
  // until a usable one has given the tracker its speed again: they then hold the last reading.
  [[nodiscard]] bool motion_known() const noexcept { return !angle_gap_ && angle_.speed_known(); }
  // Set for the one period in which a pair finished (accepted, rejected or skipped).
  [[nodiscard]] const std::optional<PairResult>& last_pair() const { return last_pair_; }
  // Set for the one period in which an estimate was published.
  [[nodiscard]] const std::optional<ResistanceEstimate>& last_estimate() const { return last_estimate_; }
  // Set for the one period in which an injection event finished, whatever its outcome.
  [[nodiscard]] const std::optional<EventEstimate>& last_event() const { return last_event_; }
  // Set for the one period in which a calibration completed.
  [[nodiscard]] const std::optional<Calibration>& calibration_completed() const { return calibration_done_; }
  // Set for the one period in which the calibration in use took a Ke0 from turning events
  // (DriveConfig::magnet_reference_max_std_C): the calibration as it now stands, to be stored.
  [[nodiscard]] const std::optional<Calibration>& magnet_reference_completed() const { return magnet_reference_done_; }
  // Set for the one period in which the calibration's rotor-angle check ended, whatever its
  // outcome. A check aborted by a stop or a lost sample, or voided by a moving operating point,
  // starts again as the sweep does (kSweepHoldoff_s, kSweepAttempts); angle_check_pending() is
  // true while that start is due.
  [[nodiscard]] const std::optional<AngleCheckResult>& angle_check_completed() const { return check_done_; }
  [[nodiscard]] bool angle_check_pending() const { return check_restart_.pending; }
  // The last check's result (outcome kNone before any).
  [[nodiscard]] const AngleCheckResult& angle_check() const { return check_.result(); }
  // The correction in use of the commissioned rotor-angle offset (0 before any was measured).
  [[nodiscard]] double angle_correction_rad() const { return angle_.offset_correction_rad(); }
  // Set for the one period in which the calibration's bridge sweep ended, whatever its outcome.
  [[nodiscard]] const std::optional<InverterSweepResult>& inverter_sweep_completed() const { return sweep_done_; }
  // A sweep the drive's stop, a lost sample or a speed still settling aborted, or whose fit
  // resolved no bridge (InverterSweepOutcome::kUnresolved), is started again once the drive has
  // run kSweepHoldoff_s without a stop, as the calibration itself resumes: a calibration asked
  // for before the drive was enabled (and so before it reached its speed), or a passing sensor
  // timeout, must not cost it the bridge's measurement. At most kSweepAttempts starts per
  // calibration (a drive that keeps stopping or changing speed goes on without it, as before).
  // True while such a start is due.
  static constexpr int kSweepAttempts = 5;
  static constexpr double kSweepHoldoff_s = 0.25;
  [[nodiscard]] bool inverter_sweep_pending() const { return sweep_restart_.pending; }
  // The last sweep's result (outcome kNone before any).
  [[nodiscard]] const InverterSweepResult& inverter_sweep() const { return sweep_.result(); }
  // True for the one period in which a calibration run failed (timed out, or refused its
  // uncertain Rs0: telemetry().calibration_failure says which).
  [[nodiscard]] bool calibration_just_failed() const { return calibration_failed_now_; }
  [[nodiscard]] const Calibration& calibration() const { return observer_.calibration(); }
  // The estimator's inverter-voltage prior now (docs/estimator.md section 4).
  [[nodiscard]] double vx_V() const { return scheduler_.vx_V(); }
  [[nodiscard]] double vx_std_V() const { return scheduler_.vx_std_V(); }
  // Its standard error at a bus this far from the reference (InjectionScheduler::vx_std_at_V).
  [[nodiscard]] double vx_std_at_V(double bus_offset_V) const { return scheduler_.vx_std_at_V(bus_offset_V); }
  [[nodiscard]] const DriveConfig& config() const { return config_; }

 private:
  [[gnu::noinline]] void handle_pair(const PairResult& r);  // (rare: out of step()'s registers)
  [[gnu::noinline]] const DriveOutput& step_without_sample(double now, std::uint32_t periods, const DriveCommand& command);
  [[nodiscard]] double measurement_age_s(const EventEstimate& e) const;
  void handle_estimate(const EventEstimate& e);
  // The filter's part of an estimate: fused `age_s` controller seconds after the time it
  // belongs to, and reported (last_estimate()).
  void fuse_estimate(const EventEstimate& e, double age_s);
  // Estimates dated after their publication (a field-weakening event's, EventEstimate::
  // measured_at_s) wait here until the filter's clock reaches their time: the filter then
  // compares each with its own estimate of that time, where a referral by the model's rate of
  // warming read a newcomer's servo 4.7 mOhm low on average (docs/estimator.md section 7).
  void hold_estimate(const EventEstimate& e);
  // At a thermal update, `dt_s` after the one before: the held estimate whose time has come
  // first is fused (one an update, and not in a step that reported another estimate).
  void fuse_held_estimate(double dt_s);
  // When the filter restarts (a calibration sets the winding's temperature, a restored state
  // replaces it): the held estimates are of the winding before, and are dropped (counted).
  void drop_held_estimates();
  // held_[i] now, referred back by the model's rate as far as its date lies ahead (a fifth
  // estimate to hold).
  void fuse_held_now(std::size_t i);
  // An Rs dated `ahead_s` after now, referred back to now by the model's rate of warming.
  [[nodiscard]] double referred_back_ohm(double rs_ohm, double ahead_s) const {
    return rs_ohm - rs_rate_ohm_per_s_ * std::max(ahead_s, 0.0);
  }
  void remove_held(std::size_t i);
  void advance_thermal(std::uint32_t periods, const DriveCommand& command);
  // Periods (at most an update's) into the thermal model's clock; its update when one is due.
  void count_thermal_periods(std::uint32_t periods, const DriveCommand& command);
  void update_thermal(double ambient_C, bool speed_mode);
  [[nodiscard]] Dq motoring_reference(const DriveCommand& command);
  // One period of field weakening (when it is on); true while its d current is still moving.
  bool weaken_field(bool levels_active, double omega_e_rad_s, bool& release_motoring);
  void hand_pulse_over(Dq& motoring_A);
  [[nodiscard]] bool field_weakened() const;  // the regulator is weakening the field now
  [[nodiscard]] bool held_on_voltage_limit() const { return limited_periods_ >= held_on_limit_periods_; }
  static constexpr double kHeldOnLimit_s = 2e-3;
  // How recent a fused resistance measurement must be for an operator's calibration temperature
  // to be checked against it (start_calibration), controller seconds.
  static constexpr double kRecentMeasurement_s = 60.0;
  // Last period's motoring current: its reference less the pulse (both zero while disabled).
  [[nodiscard]] Dq last_motoring_current_A() const {
    return {telemetry_.i_ref_A.d - telemetry_.injection_A.d, telemetry_.i_ref_A.q - telemetry_.injection_A.q};
  }

  DriveConfig config_;
  double kt_dq_Nm_per_A_;
  double speed_limit_rad_s_;  // config_.speed_limit_rad_s, or infinity without a limit
  std::uint32_t thermal_update_periods_;  // control periods in one thermal update (at least 1)
  double speed_limit_gain_Nm_s_;  // G of the torque-mode fold-back (DriveConfig::speed_limit_rad_s)
  AngleTracker angle_;
  CurrentController current_;
  FieldWeakening field_weakening_;
  SpeedController speed_;
  InjectionScheduler scheduler_;
  BaselineEstimator baseline_;
  ThermalObserver observer_;
  bool thermal_guess_pending_ = true;  // start from the ambient sensor at the first update
  void start_thermal_from_guess(double guess_C);
  void finish_inverter_sweep(double now_s);
  void finish_angle_check();
  // The angle check's and the bridge sweep's restarts, their ends on the voltage limit and the
  // check's step, while either runs or waits to start (step() keeps the sweep's step and the levels).
  void check_and_sweep_period(double now, bool enabled, bool speed_controlled, const Dq& i, double omega_e);
  void start_calibration_sweep(double now_s);
  void set_angle_correction(double correction_rad);
  [[nodiscard]] AngleCheckMotor angle_check_motor() const;
  void restore_band();
  void restore_angle();
  void age_magnet(double controller_s);
  // Thermal time since the last EMF measurement: what the updates have aged it by, plus the
  // time since the last update.
  [[nodiscard]] double magnet_age_now_s() const { return magnet_age_s_ + thermal_elapsed_s_ * observer_.time_scale(); }
  void track_motoring_voltage(double now_s, double omega_e_rad_s);
  void update_magnet(const EventEstimate& e, const Calibration& cal);
  void restore_vx();
  [[nodiscard]] double magnet_var_now_C2() const;
  void publish_magnet_std();
  void pool_ke_scatter(const EventEstimate& e, double ke_ref);
  // A calibration without Ke0: the event's Ke referred to T0 at the rotor's temperature as the
  // drive knows it, pooled until calibration_events of them, or calibration_min_events when the
  // next one no longer qualifies; then Ke0 (adopt_magnet_reference).
  void offer_magnet_reference(const EventEstimate& e);
  void adopt_magnet_reference();
  [[nodiscard]] double ke_pair_rel_var() const;
  [[nodiscard]] double magnet_ke0_var_C2() const;
  [[nodiscard]] double calibration_ke0_std(double ke0) const;
  // A Ke0 entered by hand or stored without its error: 0.2 % (1.7 C of magnet at -0.0012/C),
  // about what a back-EMF test of a few points gives.
  static constexpr double kUnknownKe0StdFraction = 0.002;
  // One pair's Ke scatter before any event has shown it (the first events of one pair each).
  static constexpr double kUnknownKePairStdFraction = 0.005;
  void fail_calibration(CalibrationFailure why);
  // The failure's status (failed, reason, outcome) and its publication, without ending a run.
  void record_calibration_failure(CalibrationFailure why);
  // A calibration event refused for its resistance outside the plausibility window: counted, and
  // kCalibrationOutsideWindowEvents of them in a row on one side refuse the calibration.
  void count_calibration_outside_window(const EventEstimate& e);
  void complete_calibration();
  void publish_calibration_state();
  void clear_motoring_telemetry();  // nothing asked of the motor this period (disabled, no sample)
  // The telemetry of what the drive has learned or been given (the angle correction, the
  // bridge's band and Vx, Lq, the calibration's flag): copied where it changes, and after a
  // step in which the scheduler learned (InjectionScheduler::learned_version), not every period.
  void publish_learned();
  // The bridge's ripple band in use, wherever it changes (configured, stored, measured, restored).
  void use_band(double band_A);
  // At a step's end: what the scheduler learned in it (the rest changes outside the scheduler,
  // where publish_learned() is called).
  void publish_learned_if_moved() {
    if (scheduler_.learned_version() != learned_version_published_) {
      publish_learned();
    }
  }
  std::uint32_t learned_version_published_ = 0;

  // The period's reports (last_pair() ... inverter_sweep_completed()): set only through
  // report(), which notes that the next step must clear them.
  template <typename T, typename V>
  void report(std::optional<T>& slot, V&& value) {
    slot = std::forward<V>(value);
    reported_ = true;
  }

  DriveOutput output_{};
  DriveTelemetry telemetry_{};
  bool reported_ = false;  // some report below is set
  std::optional<PairResult> last_pair_;
  std::optional<ResistanceEstimate> last_estimate_;
  std::optional<EventEstimate> last_event_;
  std::optional<Calibration> calibration_done_;
  std::optional<Calibration> magnet_reference_done_;
  std::optional<InverterSweepResult> sweep_done_;
  InverterSweep sweep_;
  AngleCheck check_;
  std::optional<AngleCheckResult> check_done_;
  CalibrationStepRestart check_restart_;
  bool sweep_after_check_ = false;      // the sweep starts when the check's wait has ended
  double pending_angle_jump_rad_ = 0.0; // a correction's change, for the next step's history
  // The angle correction in use came from a check (this run's or a stored calibration's), and
  // what held before the calibration in progress, restored if it does not complete.
  bool angle_measured_ = false;
  bool angle_measured_before_ = false;
  double angle_before_calibration_rad_ = 0.0;
  // The band in use came from a sweep (this run's or a stored calibration's), and what held
  // before the calibration in progress, restored if it does not complete.
  bool band_measured_ = false;
  bool band_measured_before_ = false;
  CalibrationStepRestart sweep_restart_;
  double band_before_calibration_A_ = 0.0;

  // Signed: its conversion to a time is one instruction, an unsigned one's a branch and more
  // (2^63 periods are 29 million years at 10 kHz).
  std::int64_t period_ = 0;
  // Unusable steps came after the tracker had started (the shaft may have turned on), and the
  // rotor's angle was lost (a sample after them that did not follow the last one used): the
  // bridge stays off until the tracker has the speed again.
  bool angle_gap_ = false;
  bool angle_lost_ = false;
  bool was_enabled_ = false;
  int speed_divider_ = 0;
  double torque_demand_Nm_ = 0.0;
  bool voltage_limited_since_speed_step_ = false;  // SpeedController::step's current_loop_saturated
  double speed_ramp_ref_rad_s_ = 0.0;  // the ramped speed reference (DriveConfig::speed_ramp_rad_s2)
  bool speed_loop_started_ = false;  // speed mode began: the loop took over the torque, the ramp the shaft's speed
  // History for the period record: the last two commands and the previous sample.
  bool have_previous_ = false;
  Dq previous_i_A_{};
  Abc previous_i_abc_A_{};
  double pattern_noise_A_ = 0.0;  // effective noise of the sampled line (set_current_noise_A)
  double vx_bus_slope_ = 0.0;     // dead_time / period, when Vx is referred to a bus (else 0)
  bool vx_referred_to_bus_ = false;  // DriveConfig::vx_reference_bus_V is set
  // The current loop's motoring voltage, low-passed over the periods without a pulse
  // (track_motoring_voltage), and how many periods it has seen since the loop started.
  Dq motoring_voltage_mean_V_{};
  double motoring_omega_mean_rad_s_ = 0.0;  // filtered as the mean voltage (track_motoring_voltage)
  Dq motoring_current_mean_A_{};
  // The motoring point a pair holds the field weakening at (weaken_field): its voltage before
  // the pair, and the speed and q current that voltage was at.
  struct Watch {
    bool armed = false;
    Dq v_V{};
    double omega_e_rad_s = 0.0;
    Dq i_A{};
  };
  Watch pair_watch_{};
  double motoring_voltage_mean_sq_V2_ = 0.0;  // of |v|^2
  double motoring_voltage_gain_ = 0.0;
  std::uint32_t motoring_voltage_periods_ = 0;
  std::uint32_t motoring_voltage_settle_periods_ = 0;
  PeriodSample period_sample_{};  // the period that just ended, when step() builds it
  double previous_theta_smooth_ = 0.0;
  // The commands in the stator's frame (alpha, beta), as the bridge was asked for them.
  AlphaBeta v_applied_next_ab_{};   // command of step k-1 (applies during period k)
  AlphaBeta v_applied_now_ab_{};    // command of step k-2 (applied during period k-1 -> k)
  // Whether each command was on the voltage limit, and whether the bridge may not have applied
  // it (a duty clipped, or one near a rail for its dead time, pulse_lost(): the pairs reject
  // such samples; the loop's limit alone
  // leaves the command applied as recorded). One object, shifted with the commands.
  struct CommandFlags {
    bool limited = false;
    bool clipped = false;
  };
  CommandFlags flags_next_{};
  CommandFlags flags_now_{};
  // Only on a bus below this can a command on the voltage limit put a duty near a rail for the
  // dead time (the constructor; pulse_lost() in modulation.hpp).
  double pulse_check_below_V_ = 0.0;
  double dead_time_fraction_ = 0.0;  // |control.dead_time_s| / period
  // Periods in a row whose command was limited, and how many make kHeldOnLimit_s
  // (held_on_voltage_limit: the current loop's command on the voltage limit that long). A
  // positive d level (a pair's +F, the angle check's +L, a sweep's level) raises the machine's
  // voltage by w Ld F: held there, the loop keeps its d current (the d axis has the voltage
  // first) and loses the q current. On round 5's 15 mH fan at 175 rad/s, below its
  // field-weakening speed, the bus sagging from 540 to 400 V in 20 ms while a +14.5 A level was
  // on, iq went from +2.7 to -33 A in 20 ms and the bridge tripped at 45 A (docs/estimator.md
  // section 2). A level's own step puts the loop on the limit for a few periods (the angle
  // check's at 60 rad/s on the reference); 2 ms of it is no step's, and a tenth of the time that
  // fan took from the limit to the trip.
  std::uint32_t limited_periods_ = 0;
  std::uint32_t held_on_limit_periods_ = 1;
  // Thermal accumulation.
  double i_sq_sum_ = 0.0;
  double speed_sum_ = 0.0;
  std::int64_t thermal_count_ = 0;
  int thermal_enabled_count_ = 0;  // of those periods, the ones the drive was enabled in
  double thermal_elapsed_s_ = 0.0;
  double last_baseline_publish_s_ = 0.0;
  std::uint32_t thermal_updates_ = 0;  // wraps after 1.4 years at 100 Hz: only its residue mod 10 is used
  // The present load for the time-to-limit: i^2 and speed averaged over about one injection
  // interval (1 to 10 s of drive time), so that the prediction follows the load and the
  // injection's mean heating, not whether the last 10 ms held a pulse. Negative: none yet.
  double load_i_sq_A2_ = -1.0;
  double load_speed_rad_s_ = 0.0;
  double rs_rate_ohm_per_s_ = 0.0;  // the winding resistance's predicted rate of change
  // Held estimates (hold_estimate), each with the controller time left until its date.
  static constexpr std::size_t kHeldEstimates = 4;
  std::array<EventEstimate, kHeldEstimates> held_{};
  std::array<double, kHeldEstimates> held_left_s_{};
  std::size_t held_count_ = 0;
  // Magnet.
  double magnet_filtered_C_ = 0.0;
  double magnet_var_C2_ = 0.0;          // the filter's variance at its last measurement (Ke0's apart)
  double magnet_sys_std_C_ = 0.0;       // the readings' systematic error, followed with the filter's gain
  bool magnet_reset_ = true;            // no estimate against the present Ke0 yet
  double magnet_upper_C_ = 0.0;         // estimate + confidence_sigma sigma at the last measurement
  double ke_pooled_rel_var_sum_ = 0.0;  // the events' pair scatter, pooled (relative to Ke^2)
  double ke_pooled_dof_ = 0.0;
  double calibration_ke_sq_sum_ = 0.0;
  bool magnet_valid_ = false;
  // Turning events pooled for a Ke0 the calibration in use lacks (offer_magnet_reference).
  struct MagnetReferencePool {
    int events = 0;
    int pairs = 0;
    double ke0_sum = 0.0;           // the events' Ke referred to T0, V s/rad
    double ke0_sq_sum = 0.0;
    double model_var_sum = 0.0;     // their shared and systematic Ke variances, referred likewise
    double reference_var_sum = 0.0; // the rotor temperature's share, (V s/rad)^2
    double reference_C_sum = 0.0;
    double reference_std_sum = 0.0;
  } magnet_reference_{};
  bool magnet_reference_armed_ = false;  // a calibration run at rest completed; no Ke0 taken since
  // The farthest a turning event's Ke0 may lie from the commissioned flux's (as the calibration
  // file's warning, kKe0OffMotorFraction) and still be pooled.
  static constexpr double kKe0OffMotor = 0.30;
  bool magnet_measured_ = false;  // an estimate exists (valid or aged out): the magnets derate on it
  double magnet_age_s_ = 0.0;  // thermal time since the last EMF measurement, to the last thermal update
  // Calibration.
  bool calibrating_ = false;
  bool calibration_failed_ = false;
  bool calibration_failed_now_ = false;
  bool calibration_refused_on_request_ = false;  // start_calibration refused it (kWindingWarm)
  double thermal_ambient_C_ = 0.0;  // the ambient of the filter's last update
  CalibrationFailure calibration_failure_ = CalibrationFailure::kNone;
  CalibrationOutcome calibration_outcome_ = CalibrationOutcome::kNone;
  double calibration_started_s_ = 0.0;
  double calibration_temp_C_ = 25.0;
  double calibration_t0_rise_std_C_ = 0.0;  // Calibration::t0_rise_std_C of the run under way
  // The thermal state was restored (restore_thermal_state) since the filter last started from a
  // guess: the model's rise then holds the restored state's, which is no soaked start's.
  bool thermal_restored_ = false;
  // The filter's rise beyond the model's that a calibration on the nameplate was last taken with
  // (start_calibration): its run restarted the filter at the cold end, so a repeated request and
  // one after the run failed take the larger of it and what the filter holds then. 0 again where
  // the filter starts from a guess.
  double nameplate_excess_C_ = 0.0;
  bool calibration_from_ambient_sensor_ = false;  // the running calibration's T0 is the sensor's
  int calibration_count_ = 0;
  double calibration_rs_sum_ = 0.0;
  double calibration_weight_sum_ = 0.0;
  double calibration_ke_sum_ = 0.0;
  int calibration_ke_count_ = 0;
  int calibration_ke_pairs_ = 0;
  double calibration_ke_model_var_sum_ = 0.0;
  bool calibration_vx_learned_ = false;  // an event of this calibration run learned Vx
  // This calibration run's latest events refused as outside the plausibility window, in a row
  // and on one side (+1 above it, -1 below): their count and their resistances' sums.
  int calibration_outside_count_ = 0;
  int calibration_outside_side_ = 0;
  double calibration_outside_sum_ohm_ = 0.0;
  double calibration_outside_sq_sum_ohm2_ = 0.0;
  InjectionScheduler::VxState vx_before_calibration_{};  // the scheduler's Vx state when the run started
  DeratingResult derating_{};
  // The pulses' current limit: the magnets' derating only (update_thermal).
  double injection_current_limit_A_ = 0.0;
};

}  // namespace pmsm::core
